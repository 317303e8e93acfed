"""The S3 side of tests/servers/upload.rs, through boto3 (installed with moto by
.ci/run), independent of the object_store crate that `bench` uses.

  s3_store.py setup ENDPOINT
      On a moto server started with INITIAL_NO_AUTH_ACTION_COUNT=4: an IAM
      user allowed s3:*, its access key, and the bucket `lab-bench` (the
      only unauthenticated actions); prints {"id": ..., "secret": ...}.
      Every later request must be signed with that key.
  s3_store.py objects ENDPOINT BUCKET PREFIX
      With AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY from the environment:
      every object under PREFIX as {key: {"size", "sha256",
      "last_modified", "recording"}}, "recording" being the `recording`
      column of a Parquet object (pyarrow), else null.
"""
import hashlib
import io
import json
import os
import sys

import boto3


def client(service, endpoint, key_id, secret):
    return boto3.client(
        service,
        endpoint_url=endpoint,
        region_name="us-east-1",
        aws_access_key_id=key_id,
        aws_secret_access_key=secret,
    )


def setup(endpoint):
    iam = client("iam", endpoint, "bootstrap", "bootstrap")
    iam.create_user(UserName="bench")
    iam.put_user_policy(
        UserName="bench",
        PolicyName="s3",
        PolicyDocument=json.dumps(
            {
                "Version": "2012-10-17",
                "Statement": [{"Effect": "Allow", "Action": "s3:*", "Resource": "*"}],
            }
        ),
    )
    k = iam.create_access_key(UserName="bench")["AccessKey"]
    s3 = client("s3", endpoint, k["AccessKeyId"], k["SecretAccessKey"])
    s3.create_bucket(Bucket="lab-bench")
    print(json.dumps({"id": k["AccessKeyId"], "secret": k["SecretAccessKey"]}))


def objects(endpoint, bucket, prefix):
    s3 = client(
        "s3",
        endpoint,
        os.environ["AWS_ACCESS_KEY_ID"],
        os.environ["AWS_SECRET_ACCESS_KEY"],
    )
    out = {}
    pages = s3.get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=prefix)
    for page in pages:
        for o in page.get("Contents", []):
            body = s3.get_object(Bucket=bucket, Key=o["Key"])["Body"].read()
            recording = None
            if o["Key"].endswith(".parquet"):
                import pyarrow.parquet as pq

                t = pq.read_table(io.BytesIO(body))
                recording = t.column("recording").to_pylist()[0]
            out[o["Key"]] = {
                "size": o["Size"],
                "sha256": hashlib.sha256(body).hexdigest(),
                "last_modified": o["LastModified"].isoformat(),
                "recording": recording,
            }
    print(json.dumps(out))


if __name__ == "__main__":
    if sys.argv[1] == "setup":
        setup(sys.argv[2])
    elif sys.argv[1] == "objects":
        objects(*sys.argv[2:5])
    else:
        sys.exit(f"unknown command {sys.argv[1]}")
