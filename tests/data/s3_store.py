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
  s3_store.py selfsigned DIR
      A test CA (DIR/ca.pem) and a certificate it signed for 127.0.0.1 and
      localhost, with its key (DIR/cert.pem, DIR/key.pem), by the
      `cryptography` package moto brings: for a TLS front to moto.
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


def selfsigned(out_dir):
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    now = datetime.datetime.now(datetime.timezone.utc)

    def cert(subject, key, issuer, issuer_key, ca):
        b = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, subject)]))
            .issuer_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, issuer)]))
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True)
        )
        if not ca:
            b = b.add_extension(
                x509.SubjectAlternativeName(
                    [x509.IPAddress(ipaddress.ip_address("127.0.0.1")), x509.DNSName("localhost")]
                ),
                critical=False,
            )
        return b.sign(issuer_key, hashes.SHA256())

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = cert("bench test CA", ca_key, "bench test CA", ca_key, True)
    key = ec.generate_private_key(ec.SECP256R1())
    leaf = cert("127.0.0.1", key, "bench test CA", ca_key, False)
    for name, data in [
        ("ca.pem", ca.public_bytes(serialization.Encoding.PEM)),
        ("cert.pem", leaf.public_bytes(serialization.Encoding.PEM)),
        (
            "key.pem",
            key.private_bytes(
                serialization.Encoding.PEM,
                serialization.PrivateFormat.PKCS8,
                serialization.NoEncryption(),
            ),
        ),
    ]:
        with open(os.path.join(out_dir, name), "wb") as f:
            f.write(data)


if __name__ == "__main__":
    if sys.argv[1] == "setup":
        setup(sys.argv[2])
    elif sys.argv[1] == "objects":
        objects(*sys.argv[2:5])
    elif sys.argv[1] == "selfsigned":
        selfsigned(sys.argv[2])
    else:
        sys.exit(f"unknown command {sys.argv[1]}")
