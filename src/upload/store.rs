//! The store a `--upload`/`--to` URL names: parsed and checked
//! ([`StoreUrl::parse`]), opened ([`Store::open`]) and probed
//! ([`Store::probe`]): by `bench upload` before it uploads, by `bench
//! serve --upload` in the background (`crate::daemon`).

use object_store::aws::{AmazonS3Builder, AmazonS3ConfigKey};
use object_store::local::LocalFileSystem;
use object_store::path::Path as ObjectPath;
use object_store::{BackoffConfig, ClientConfigKey, ObjectStore, RetryConfig};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// Where uploads go: an S3 bucket and key prefix, or a directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StoreUrl {
    /// `s3://BUCKET[/PREFIX]`: an S3-compatible store; the endpoint,
    /// region and credentials from the `AWS_*` environment.
    S3 {
        /// The bucket.
        bucket: String,
        /// The key prefix, without leading or trailing `/` (may be empty).
        prefix: String,
    },
    /// `file:///DIR[/…]`: a directory (a NAS mount) that must exist.
    File {
        /// The absolute directory.
        dir: PathBuf,
    },
}

impl std::fmt::Display for StoreUrl {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::S3 { bucket, prefix } if prefix.is_empty() => write!(f, "s3://{bucket}"),
            Self::S3 { bucket, prefix } => write!(f, "s3://{bucket}/{prefix}"),
            Self::File { dir } => write!(f, "file://{}", dir.display()),
        }
    }
}

impl StoreUrl {
    /// Parses `s3://BUCKET[/PREFIX]` or `file:///ABSOLUTE/DIR`.
    ///
    /// A bucket name follows S3's rules (3–63 characters: lowercase
    /// letters, digits, `.` and `-`, starting and ending with a letter or
    /// digit); a prefix's segments are non-empty and are neither `.` nor
    /// `..`; no part holds a space, a control character, `?` or `#`.
    ///
    /// # Errors
    /// The reason, for the caller to name its flag with.
    pub fn parse(s: &str) -> Result<Self, String> {
        if s.chars().any(|c| c.is_whitespace() || c.is_control()) {
            return Err("holds a space or a control character".into());
        }
        if s.contains(['?', '#']) {
            return Err("holds `?` or `#`: a store URL has no query or fragment".into());
        }
        let Some((scheme, rest)) = s.split_once("://") else {
            return Err(
                "is not a store URL: s3://BUCKET/PREFIX or file:///DIRECTORY (an absolute path)"
                    .into(),
            );
        };
        match scheme {
            "s3" => {
                let rest = rest.trim_end_matches('/');
                let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
                check_bucket(bucket)?;
                if !prefix.is_empty() {
                    for seg in prefix.split('/') {
                        if seg.is_empty() || seg == "." || seg == ".." {
                            return Err(format!(
                                "the prefix {prefix:?} has an empty, `.` or `..` segment"
                            ));
                        }
                    }
                }
                Ok(Self::S3 {
                    bucket: bucket.into(),
                    prefix: prefix.into(),
                })
            }
            "file" => {
                if !rest.starts_with('/') {
                    return Err(format!(
                        "file://{rest} is not an absolute path: file:///DIRECTORY (three slashes)"
                    ));
                }
                let dir = PathBuf::from(rest);
                if dir
                    .components()
                    .any(|c| matches!(c, std::path::Component::ParentDir))
                {
                    return Err("the directory holds `..`".into());
                }
                match std::fs::metadata(&dir) {
                    Ok(m) if m.is_dir() => Ok(Self::File { dir }),
                    Ok(_) => Err(format!("{} is not a directory", dir.display())),
                    Err(e) => Err(format!("{}: {e}", dir.display())),
                }
            }
            "" => Err("has no scheme: s3://BUCKET/PREFIX or file:///DIRECTORY".into()),
            other => Err(format!(
                "the scheme {other:?} is not supported (s3:// for an S3-compatible store, file:// for a directory)"
            )),
        }
    }

    /// The object URL of `key` (a key under the store's root, for the
    /// catalogue's `recording` column): `s3://BUCKET/KEY` or
    /// `file:///DIR/KEY`, the key's segments percent-encoded as
    /// [`crate::jobs::catalogue::object_url`] does.
    pub fn object_url(&self, key: &str) -> String {
        let root = match self {
            Self::S3 { bucket, .. } => format!("s3://{bucket}"),
            Self::File { dir } => format!("file://{}", dir.display()),
        };
        let mut url = root.trim_end_matches('/').to_string();
        for seg in key.split('/') {
            url = crate::jobs::catalogue::object_url(&url, seg);
        }
        url
    }

    /// The key of the file `name` (a relative path such as
    /// `catalogue/x.parquet`) under the store's prefix.
    pub fn key_of(&self, name: &str) -> String {
        match self {
            Self::S3 { prefix, .. } if !prefix.is_empty() => format!("{prefix}/{name}"),
            _ => name.to_string(),
        }
    }
}

/// S3's bucket naming rules (the general purpose buckets').
fn check_bucket(b: &str) -> Result<(), String> {
    if b.is_empty() {
        return Err("names no bucket: s3://BUCKET/PREFIX".into());
    }
    let ok_chars = b
        .chars()
        .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '.' || c == '-');
    let ends_ok = |c: Option<char>| c.is_some_and(|c| c.is_ascii_lowercase() || c.is_ascii_digit());
    if !(3..=63).contains(&b.len())
        || !ok_chars
        || !ends_ok(b.chars().next())
        || !ends_ok(b.chars().last())
        || b.contains("..")
    {
        return Err(format!(
            "{b:?} is not an S3 bucket name (3–63 characters: lowercase letters, digits, `.` and `-`, starting and ending with a letter or digit)"
        ));
    }
    Ok(())
}

/// How long the store has to answer by default, seconds
/// (`--store-timeout`, [`check_timeout_s`]).
pub const DEFAULT_TIMEOUT_S: f64 = 10.0;

/// The range of `--store-timeout`, seconds.
pub const TIMEOUT_RANGE_S: (f64, f64) = (0.5, 300.0);

/// How long one whole request may take, seconds, however steadily the
/// store answers: reading back a recording of several GB on a slow link
/// (a store that stops answering is caught by the timeout, not by this).
pub const WHOLE_REQUEST_TIMEOUT_S: u64 = 3600;

/// Checks a `--store-timeout` value: within [`TIMEOUT_RANGE_S`].
///
/// # Errors
/// Why not, for the caller to name its flag with.
pub fn check_timeout_s(s: f64) -> Result<Duration, String> {
    let (lo, hi) = TIMEOUT_RANGE_S;
    if s.is_finite() && (lo..=hi).contains(&s) {
        Ok(Duration::from_secs_f64(s))
    } else {
        Err(format!("{s} s is out of range ({lo} to {hi} s)"))
    }
}

/// An opened store.
#[derive(Debug, Clone)]
pub struct Store {
    /// What it was opened from.
    pub url: StoreUrl,
    pub(super) inner: Arc<dyn ObjectStore>,
    /// How long the store has to connect, and to answer each request (its
    /// first byte, and each read after it).
    pub timeout: Duration,
}

/// Why a store cannot be used, as the probe found.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ProbeError {
    /// The store answered and refused: no such bucket, credentials it does
    /// not accept. A configuration error (exit 2 before anything starts).
    #[error("{0}")]
    Refused(String),
    /// The store did not answer (connection refused, timeout, DNS): an
    /// outage, retried.
    #[error("{0}")]
    Unreachable(String),
}

impl Store {
    /// Opens the store of `url`. For `s3://`, the environment gives
    /// `AWS_ACCESS_KEY_ID` and `AWS_SECRET_ACCESS_KEY` (required),
    /// `AWS_REGION` (default `us-east-1`), `AWS_ENDPOINT` (an S3-compatible
    /// server's URL: MinIO, Ceph, Garage…; default AWS) and
    /// `AWS_ALLOW_HTTP=true` for an `http://` endpoint. The store has
    /// `timeout` to take a connection, and `timeout` to answer a request
    /// (from when it is sent to the first byte of the answer, then between
    /// two reads of it); a whole request may take at most
    /// [`WHOLE_REQUEST_TIMEOUT_S`]. A request that fails fast is retried by
    /// the client at most twice within `timeout`; one that timed out is
    /// not (the caller's own backoff does the rest). Every call on the
    /// store (a directory's too: a NAS that hangs) is also given up after
    /// `timeout` without an answer ([`Self::within`]).
    ///
    /// # Errors
    /// The reason (missing credentials, a builder's refusal).
    pub fn open(url: StoreUrl, timeout: Duration) -> Result<Self, String> {
        let ms = |d: Duration| format!("{}ms", d.as_millis().max(1));
        let inner: Arc<dyn ObjectStore> = match &url {
            StoreUrl::S3 { bucket, .. } => {
                for var in ["AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"] {
                    if std::env::var_os(var).is_none_or(|v| v.is_empty()) {
                        return Err(format!(
                            "{var} is not set: an s3:// store takes its credentials from AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (and AWS_ENDPOINT for a server other than AWS)"
                        ));
                    }
                }
                // TLS: rustls with *ring*, the one provider compiled in,
                // as the process's default (reqwest takes that one; a
                // second call finds it installed, which is fine).
                let _ = rustls::crypto::ring::default_provider().install_default();
                let mut b = AmazonS3Builder::from_env()
                    .with_bucket_name(bucket)
                    // Set on the options `from_env` made (AWS_ALLOW_HTTP…).
                    .with_config(
                        AmazonS3ConfigKey::Client(ClientConfigKey::ConnectTimeout),
                        ms(timeout),
                    )
                    .with_config(
                        AmazonS3ConfigKey::Client(ClientConfigKey::ReadTimeout),
                        ms(timeout),
                    )
                    .with_config(
                        AmazonS3ConfigKey::Client(ClientConfigKey::Timeout),
                        format!("{WHOLE_REQUEST_TIMEOUT_S} seconds"),
                    )
                    .with_retry(RetryConfig {
                        backoff: BackoffConfig::default(),
                        max_retries: 2,
                        // A request that timed out has used it all.
                        retry_timeout: timeout,
                    });
                if std::env::var_os("AWS_REGION").is_none()
                    && std::env::var_os("AWS_DEFAULT_REGION").is_none()
                {
                    b = b.with_region("us-east-1");
                }
                Arc::new(b.build().map_err(|e| e.to_string())?)
            }
            StoreUrl::File { dir } => {
                Arc::new(LocalFileSystem::new_with_prefix(dir).map_err(|e| e.to_string())?)
            }
        };
        Ok(Self {
            url,
            inner,
            timeout,
        })
    }

    /// `call` on the store, given up after [`Self::timeout`] without an
    /// answer (an `object_store` error saying so).
    ///
    /// # Errors
    /// The call's, or the timeout's.
    pub(super) async fn within<T>(
        &self,
        call: impl std::future::Future<Output = object_store::Result<T>>,
    ) -> object_store::Result<T> {
        match tokio::time::timeout(self.timeout, call).await {
            Ok(r) => r,
            Err(_) => Err(object_store::Error::Generic {
                store: "bench",
                source: format!(
                    "no answer within {} s (--store-timeout)",
                    self.timeout.as_secs_f64()
                )
                .into(),
            }),
        }
    }

    /// The object path of `key`.
    pub(super) fn path(key: &str) -> ObjectPath {
        ObjectPath::from(key)
    }

    /// Asks the store for a listing under the prefix: the bucket exists
    /// and takes the credentials, or why not.
    ///
    /// # Errors
    /// [`ProbeError::Refused`] (no such bucket, credentials refused),
    /// [`ProbeError::Unreachable`] (anything else: no answer).
    pub async fn probe(&self) -> Result<(), ProbeError> {
        let prefix = match &self.url {
            StoreUrl::S3 { prefix, .. } if !prefix.is_empty() => Some(Self::path(prefix)),
            _ => None,
        };
        match self
            .within(self.inner.list_with_delimiter(prefix.as_ref()))
            .await
        {
            Ok(_) => Ok(()),
            Err(e) => Err(classify(&e)),
        }
    }
}

/// A store error as the probe reports it.
pub(super) fn classify(e: &object_store::Error) -> ProbeError {
    use object_store::Error as E;
    let chain = crate::error::error_chain(e);
    match e {
        E::NotFound { .. } => ProbeError::Refused(format!(
            "the bucket does not exist (the store answered 404 Not Found): {chain}"
        )),
        E::PermissionDenied { .. } | E::Unauthenticated { .. } => ProbeError::Refused(format!(
            "the store refused the credentials (AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY): {chain}"
        )),
        _ if chain.contains("NoSuchBucket") => {
            ProbeError::Refused(format!("the bucket does not exist: {chain}"))
        }
        _ if chain.contains("URL scheme is not allowed") => ProbeError::Refused(
            "the endpoint (AWS_ENDPOINT) is http://, which is refused unless AWS_ALLOW_HTTP=true"
                .into(),
        ),
        // rustls' `Error::InvalidCertificate`: not a store that is away,
        // one this machine does not trust (retrying cannot help).
        _ if chain.contains("invalid peer certificate") => ProbeError::Refused(format!(
            "the store's TLS certificate is not trusted here (the system's roots, or SSL_CERT_FILE / SSL_CERT_DIR): {chain}"
        )),
        _ if chain.contains("InvalidAccessKeyId") || chain.contains("SignatureDoesNotMatch") => {
            ProbeError::Refused(format!("the store refused the credentials: {chain}"))
        }
        _ => ProbeError::Unreachable(format!("the store did not answer: {chain}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn store_urls_parse_and_bad_ones_say_why() {
        assert_eq!(
            StoreUrl::parse("s3://lab-bench/recordings/bench3/").unwrap(),
            StoreUrl::S3 {
                bucket: "lab-bench".into(),
                prefix: "recordings/bench3".into()
            }
        );
        assert_eq!(
            StoreUrl::parse("s3://lab-bench").unwrap().key_of("a.mcap"),
            "a.mcap"
        );
        let u = StoreUrl::parse("s3://lab/p").unwrap();
        assert_eq!(u.key_of("catalogue/x.parquet"), "p/catalogue/x.parquet");
        assert_eq!(u.object_url("p/a b.mcap"), "s3://lab/p/a%20b.mcap");
        assert!(matches!(
            StoreUrl::parse("file:///tmp").unwrap(),
            StoreUrl::File { .. }
        ));
        for bad in [
            "",
            "lab/recordings",
            "s3://",
            "s3://ab",
            "s3://Lab",
            "s3://-lab",
            "s3://lab_bench",
            "s3://lab..bench",
            "s3://lab//x",
            "s3://lab/a/../b",
            "s3://lab/x?y",
            "s3://lab/x#y",
            "s3://lab /x",
            "gs://lab/x",
            "http://minio:9000/lab",
            "file://relative/dir",
            "file:///does/not/exist/at/all",
            "file:///etc/hostname",
            "file:///tmp/../etc",
            "://lab",
        ] {
            assert!(StoreUrl::parse(bad).is_err(), "{bad:?} parsed");
        }
    }
}
