//! The daemon's wire protocol: error kinds and responses, `status`,
//! events, and how a request's `params` become a job request. May use
//! `jobs::request` and `serde`; nothing here touches the bench.

use crate::error::RunError;
use crate::jobs::request::JobRequest;
use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;
use serde_json::{json, Value};

/// The kind of an error response: what the client may do about it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ApiErrorKind {
    /// Not UTF-8, not JSON, not an object, a key twice, no `cmd`, or a
    /// line over [`MAX_LINE_BYTES`](super::MAX_LINE_BYTES).
    BadRequest,
    /// No such command.
    UnknownCommand,
    /// A parameter is missing, unknown or out of its range.
    BadParams,
    /// A job is running; or, and the connection is then closed, too many
    /// clients or no file descriptor left.
    Busy,
    /// A fault is latched: `reset` first.
    Faulted,
    /// The loop check refused the controller; nothing was enabled.
    Refused,
    /// The job ended in a safety fault (0 A, recording finished).
    Fault,
    /// The job ended in a HAL error (0 A, recording finished).
    Hal,
    /// The job was stopped (0 A, recording finished).
    Interrupted,
    /// Anything else.
    #[serde(other)]
    Error,
}

impl ApiErrorKind {
    /// The kind's name on the wire (`bad_params`, `fault`, …).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::BadRequest => "bad_request",
            Self::UnknownCommand => "unknown_command",
            Self::BadParams => "bad_params",
            Self::Busy => "busy",
            Self::Faulted => "faulted",
            Self::Refused => "refused",
            Self::Fault => "fault",
            Self::Hal => "hal",
            Self::Interrupted => "interrupted",
            Self::Error => "error",
        }
    }

    /// The kind a run's error answers with.
    pub fn of_run(e: &RunError) -> Self {
        match e {
            RunError::BadInput(_) | RunError::BadOption { .. } => Self::BadParams,
            RunError::Refused(_) => Self::Refused,
            RunError::Fault { .. } => Self::Fault,
            RunError::Hal { .. } => Self::Hal,
            RunError::Interrupted { .. } => Self::Interrupted,
            RunError::TickLimit { .. }
            | RunError::Record(_)
            | RunError::Output { .. }
            | RunError::Json(_)
            | RunError::Thread(_) => Self::Error,
        }
    }
}

/// An error response: `{"kind": KIND, "message": "..", "summary": {..}}`,
/// `summary` only for a job that ended without its own summary but with
/// a finished recording (fault, HAL error, stop, tick budget): the run's
/// outcome, fault, recording and catalogue row, as the local CLI's `--json`
/// prints them ([`crate::jobs::catalogue::ended_run_summary`]).
#[derive(Debug, Clone, Serialize)]
pub(super) struct ApiError {
    pub(super) kind: ApiErrorKind,
    /// (Boxed, as the summary: a job's error travels in every `JobResult`.)
    pub(super) message: Box<str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) summary: Option<Box<Value>>,
}

impl ApiError {
    pub(super) fn new(kind: ApiErrorKind, message: impl Into<String>) -> Self {
        Self {
            kind,
            message: message.into().into_boxed_str(),
            summary: None,
        }
    }

    pub(super) fn from_run(e: &RunError) -> Self {
        Self {
            summary: crate::jobs::catalogue::ended_run_summary(e).map(Box::new),
            ..Self::new(ApiErrorKind::of_run(e), format!("{e:#}"))
        }
    }
}

/// The latched fault as `status` reports it: the supervisor's fault name
/// (`probe_not_finite`, `link`, `hal`, ...) and what caused it.
#[derive(Debug, Clone, Serialize)]
pub(super) struct FaultStatus {
    pub(super) kind: &'static str,
    pub(super) message: String,
}

/// The daemon's state, as `status` reports it.
#[derive(Debug, Clone, Serialize)]
pub(super) struct Status {
    /// `disabled`, `enabled`, `running` or `faulted`.
    pub(super) state: &'static str,
    /// The latched fault.
    pub(super) fault: Option<FaultStatus>,
    /// The running job.
    pub(super) job: Option<JobStatus>,
    pub(super) backend: String,
    pub(super) rate_hz: f64,
    /// Last reading, m.
    pub(super) position_m: f64,
    /// Last current commanded, A (0 between jobs unless a hold controller
    /// holds the position).
    pub(super) command_a: f64,
    /// What holds the stage between jobs when enabled: `zero_current`, or
    /// `position (controller NAME)` (`[daemon] hold_controller`).
    pub(super) hold: String,
    /// The pace of a job whose request gives none (`bench serve --pace`):
    /// a factor of real time, `off`, or `null`: real time.
    pub(super) pace: Option<crate::jobs::request::Pace>,
    pub(super) jobs_run: u64,
    pub(super) last_recording: Option<String>,
    /// Jobs abandoned (not done [`super::JOB_STOP_TIMEOUT_MS`] after
    /// `stop`, or over their memory budget) whose threads have not ended.
    pub(super) abandoned_jobs: Vec<AbandonedJob>,
    /// The store of `--upload` (`null` without it), filled in when
    /// `status` is answered.
    pub(super) store: Option<StoreStatus>,
}

/// What the daemon knows of the store of `--upload`, as `status` shows it
/// and the `upload_store` event reports each change of it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(super) struct StoreStatus {
    /// The store's URL.
    pub(super) url: String,
    pub(super) state: StoreState,
    /// Why it is `unreachable` or `refused` (the last probe's error).
    pub(super) reason: Option<String>,
    /// How long the store has to connect and to answer each request, s
    /// (`--store-timeout`).
    pub(super) timeout_s: f64,
}

/// The store's state, as the daemon's probe (a listing under the prefix)
/// found it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum StoreState {
    /// The first probe has not answered yet.
    Probing,
    /// The store answered: the bucket is there and takes the credentials.
    Answering,
    /// The store did not answer (refused connection, timeout, DNS); the
    /// probe is tried again with the uploader's backoff until it does.
    Unreachable,
    /// The store answered and refused (no such bucket, credentials
    /// refused, an `http://` endpoint not allowed). Found after the
    /// daemon opened the bench, it is reported and the daemon runs on,
    /// the recordings queued; not probed again.
    Refused,
}

/// A job abandoned whose thread has not ended, as `status` shows it.
#[derive(Debug, Clone, Serialize)]
pub(super) struct AbandonedJob {
    pub(super) id: u64,
    pub(super) kind: &'static str,
    /// What its threads hold, bytes (0 for a bench job: not counted).
    pub(super) memory_bytes: u64,
}

#[derive(Debug, Clone, Serialize)]
pub(super) struct JobStatus {
    pub(super) id: u64,
    pub(super) kind: &'static str,
    pub(super) ticks: u64,
    /// Ticks of a bench job (chirp, control); cells of a campaign; 0 for
    /// the jobs without progress (fit, analyze, map).
    pub(super) total_ticks: u64,
    /// The recording of a bench job (`null` for the other jobs).
    pub(super) recording: Option<String>,
    pub(super) detach: bool,
}

pub(super) fn event(kind: &str, fields: Value) -> String {
    let mut v = json!({ "event": kind, "unix_time_s": unix_time_s() });
    if let (Some(o), Value::Object(f)) = (v.as_object_mut(), fields) {
        o.extend(f);
    }
    v.to_string()
}

pub(super) fn unix_time_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// A job summary as JSON (the response's `result`).
pub(super) fn to_json<T: Serialize>(summary: T) -> Result<Value, (ApiError, RunError)> {
    serde_json::to_value(summary).map_err(|e| {
        (
            ApiError::new(ApiErrorKind::Error, e.to_string()),
            RunError::Json(e),
        )
    })
}

/// Deserialises `params` (an object, or absent) as `T`, naming the
/// parameter at fault: `params.KEY: why`.
pub(super) fn from_params<T: serde::de::DeserializeOwned>(params: Value) -> Result<T, ApiError> {
    use serde::de::{value::MapAccessDeserializer, DeserializeSeed, IntoDeserializer, MapAccess};
    /// The object's entries; `at` is the key being read until its value
    /// has been read.
    struct Entries {
        iter: serde_json::map::IntoIter,
        value: Option<Value>,
        at: Option<String>,
    }
    impl<'de> MapAccess<'de> for Entries {
        type Error = serde_json::Error;
        fn next_key_seed<K: DeserializeSeed<'de>>(
            &mut self,
            seed: K,
        ) -> Result<Option<K::Value>, Self::Error> {
            let Some((k, v)) = self.iter.next() else {
                return Ok(None);
            };
            self.value = Some(v);
            self.at = Some(k.clone());
            seed.deserialize(k.into_deserializer()).map(Some)
        }
        fn next_value_seed<V: DeserializeSeed<'de>>(
            &mut self,
            seed: V,
        ) -> Result<V::Value, Self::Error> {
            let v = seed.deserialize(self.value.take().unwrap_or(Value::Null))?;
            self.at = None;
            Ok(v)
        }
    }
    let map = match params {
        Value::Null => serde_json::Map::new(),
        Value::Object(m) => m,
        _ => {
            return Err(ApiError::new(
                ApiErrorKind::BadParams,
                "params must be an object",
            ))
        }
    };
    let mut entries = Entries {
        iter: map.into_iter(),
        value: None,
        at: None,
    };
    let parsed = T::deserialize(MapAccessDeserializer::new(&mut entries));
    parsed.map_err(|e| {
        let at = entries.at.map_or(String::new(), |k| format!(".{k}"));
        ApiError::new(ApiErrorKind::BadParams, format!("params{at}: {e}"))
    })
}

/// The job request of a job command (one of [`JobRequest::KINDS`]), and
/// whether it asked to `detach` (a transport option of the daemon, not
/// part of the job).
pub(super) fn job_request(cmd: &str, params: &Value) -> Result<(JobRequest, bool), ApiError> {
    let mut params = params.clone();
    let detach = match params.as_object_mut().and_then(|m| m.remove("detach")) {
        None | Some(Value::Null) => false,
        Some(Value::Bool(d)) => d,
        Some(v) => {
            return Err(ApiError::new(
                ApiErrorKind::BadParams,
                format!("params.detach: expected true or false, got {v}"),
            ))
        }
    };
    let request = match cmd {
        "chirp" => JobRequest::Chirp(from_params(params)?),
        "control" => JobRequest::Control(from_params(params)?),
        "fit" => JobRequest::Fit(from_params(params)?),
        "design" => JobRequest::Design(from_params(params)?),
        "analyze" => JobRequest::Analyze(from_params(params)?),
        "map" => JobRequest::Map(from_params(params)?),
        "plot" => JobRequest::Plot(from_params(params)?),
        "campaign" => JobRequest::Campaign(from_params(params)?),
        "catalogue" => JobRequest::Catalogue(from_params(params)?),
        "export" => JobRequest::Export(from_params(params)?),
        "recover" => JobRequest::Recover(from_params(params)?),
        "upload" => JobRequest::Upload(from_params(params)?),
        "track" => JobRequest::Track(from_params(params)?),
        other => {
            return Err(ApiError::new(
                ApiErrorKind::UnknownCommand,
                format!("{other:?} is not a job"),
            ))
        }
    };
    Ok((request, detach))
}

/// A request's `id` exactly as the client wrote it (raw JSON text, echoed
/// byte for byte: big integers, `1e400`, escapes and nesting survive).
pub(super) type Id = Box<RawValue>;

/// The `id` of answers to lines that have none (or none that could be
/// read): `null`.
pub(super) fn null_id() -> Id {
    RawValue::from_string("null".into()).unwrap_or_else(|_| unreachable!("null is JSON"))
}

/// One response line: `{"id": ID, "ok": true, "result": ..}` or
/// `{"id": ID, "ok": false, "error": {"kind": .., "message": ..}}`.
pub(super) fn respond(id: &RawValue, r: Result<Value, ApiError>) -> String {
    #[derive(Serialize)]
    struct Response<'a> {
        id: &'a RawValue,
        ok: bool,
        #[serde(skip_serializing_if = "Option::is_none")]
        result: Option<Value>,
        #[serde(skip_serializing_if = "Option::is_none")]
        error: Option<ApiError>,
    }
    let (ok, result, error) = match r {
        Ok(v) => (true, Some(v), None),
        Err(e) => (false, None, Some(e)),
    };
    serde_json::to_string(&Response {
        id,
        ok,
        result,
        error,
    })
    .unwrap_or_else(|e| {
        // A `Value` with a non-string key cannot occur; never panic here.
        json!({ "id": null, "ok": false, "error": { "kind": "error", "message": e.to_string() } })
            .to_string()
    })
}

/// A request line, read: the `id` as sent, the `cmd`, the `params`
/// (`null` when absent).
pub(super) struct Request {
    pub(super) id: Id,
    pub(super) cmd: String,
    pub(super) params: Value,
}

/// The entries of one JSON object, in order, values unparsed.
struct Entries<'a>(Vec<(String, &'a RawValue)>);

impl<'de: 'a, 'a> Deserialize<'de> for Entries<'a> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<'a>(std::marker::PhantomData<&'a ()>);
        impl<'de: 'a, 'a> serde::de::Visitor<'de> for V<'a> {
            type Value = Entries<'a>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a JSON object")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<Entries<'a>, A::Error> {
                let mut v = Vec::new();
                while let Some(k) = map.next_key::<String>()? {
                    v.push((k, map.next_value::<&'a RawValue>()?));
                }
                Ok(Entries(v))
            }
        }
        d.deserialize_map(V(std::marker::PhantomData))
    }
}

/// The first key that appears twice in `entries`.
fn duplicate<'e>(entries: &'e [(String, &RawValue)]) -> Option<&'e str> {
    let mut seen = std::collections::HashSet::with_capacity(entries.len());
    entries
        .iter()
        .find(|(k, _)| !seen.insert(k.as_str()))
        .map(|(k, _)| k.as_str())
}

/// Refuses a duplicate key anywhere in `raw` (`at`: where `raw` is in the
/// request, for the message), and nesting deeper than
/// [`MAX_JSON_DEPTH`](super::MAX_JSON_DEPTH). Leaves (numbers, strings)
/// are never converted, so any number the grammar allows passes.
fn check_unique(raw: &RawValue, at: &str, depth: usize) -> Result<(), String> {
    let text = raw.get();
    let nested = match text.as_bytes().first() {
        Some(b'{' | b'[') => true,
        _ => return Ok(()),
    };
    if nested && depth >= super::MAX_JSON_DEPTH {
        return Err(format!(
            "{at} is nested deeper than {} levels",
            super::MAX_JSON_DEPTH
        ));
    }
    if text.starts_with('{') {
        let Entries(entries) = serde_json::from_str(text).map_err(|e| format!("{at}: {e}"))?;
        if let Some(k) = duplicate(&entries) {
            return Err(format!("duplicate key {k:?} in {at}"));
        }
        for (k, v) in &entries {
            check_unique(v, &format!("{at}.{k}"), depth + 1)?;
        }
    } else {
        let items: Vec<&RawValue> = serde_json::from_str(text).map_err(|e| format!("{at}: {e}"))?;
        for (i, v) in items.iter().enumerate() {
            check_unique(v, &format!("{at}[{i}]"), depth + 1)?;
        }
    }
    Ok(())
}

/// Reads one request line (without its newline): UTF-8, one JSON object
/// with no duplicate key at any level, a `cmd` string. On error, the
/// answer's `id` (the request's when it could be read, else `null`) and a
/// `bad_request` (or `bad_params` for `params` that are JSON but hold a
/// number out of the range of a double).
pub(super) fn parse_request(line: &[u8]) -> Result<Request, (Id, ApiError)> {
    let bad = |id: Id, m: String| (id, ApiError::new(ApiErrorKind::BadRequest, m));
    let text = std::str::from_utf8(line).map_err(|e| {
        bad(
            null_id(),
            format!("not UTF-8: invalid byte at offset {}", e.valid_up_to()),
        )
    })?;
    let top: &RawValue =
        serde_json::from_str(text).map_err(|e| bad(null_id(), format!("not JSON: {e}")))?;
    if !top.get().starts_with('{') {
        return Err(bad(
            null_id(),
            "a request is a JSON object: {\"id\": .., \"cmd\": .., \"params\": {..}}".into(),
        ));
    }
    let Entries(entries) =
        serde_json::from_str(top.get()).map_err(|e| bad(null_id(), format!("not JSON: {e}")))?;
    if let Some(k) = duplicate(&entries) {
        return Err(bad(
            null_id(),
            format!("duplicate key {k:?} in the request object"),
        ));
    }
    let get = |name: &str| entries.iter().find(|(k, _)| k == name).map(|(_, v)| *v);
    // The id first, so that later errors can be answered with it.
    let id = match get("id") {
        Some(raw) => {
            check_unique(raw, "id", 1).map_err(|m| bad(null_id(), m))?;
            raw.to_owned()
        }
        None => null_id(),
    };
    for (k, v) in &entries {
        if k != "id" {
            check_unique(v, k, 1).map_err(|m| bad(id.clone(), m))?;
        }
    }
    let Some(cmd) = get("cmd").and_then(|c| serde_json::from_str::<String>(c.get()).ok()) else {
        return Err(bad(id, "no \"cmd\" string".into()));
    };
    let params = match get("params") {
        None => Value::Null,
        Some(p) => serde_json::from_str(p.get()).map_err(|e| {
            (
                id.clone(),
                ApiError::new(ApiErrorKind::BadParams, format!("params: {e}")),
            )
        })?,
    };
    Ok(Request { id, cmd, params })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refused(line: &[u8]) -> (String, ApiError) {
        match parse_request(line) {
            Ok(_) => panic!("accepted {:?}", String::from_utf8_lossy(line)),
            Err((id, e)) => (id.get().to_string(), e),
        }
    }

    #[test]
    fn error_kind_names_are_the_wire_names() {
        use ApiErrorKind as K;
        for k in [
            K::BadRequest,
            K::UnknownCommand,
            K::BadParams,
            K::Busy,
            K::Faulted,
            K::Refused,
            K::Fault,
            K::Hal,
            K::Interrupted,
            K::Error,
        ] {
            assert_eq!(serde_json::to_value(k).unwrap(), json!(k.as_str()));
        }
    }

    #[test]
    fn ids_are_kept_as_sent() {
        for id in [
            "18446744073709551616",
            "1e400",
            "-0.0",
            "\"a\\\"\\u00e9😀\"",
            "[1, {\"k\" : [1e400]}]",
        ] {
            let r = parse_request(format!("{{\"id\": {id} , \"cmd\": \"status\"}}").as_bytes())
                .unwrap_or_else(|e| panic!("{id}: {:?}", e.1.message));
            assert_eq!(r.id.get(), id);
            assert!(respond(&r.id, Ok(json!(1))).starts_with(&format!("{{\"id\":{id},")));
        }
        assert_eq!(
            parse_request(br#"{"cmd":"status"}"#).unwrap().id.get(),
            "null"
        );
    }

    #[test]
    fn duplicates_are_refused_at_every_level() {
        for (line, key, at) in [
            (
                &br#"{"cmd":"a","cmd":"b"}"#[..],
                "cmd",
                "the request object",
            ),
            (
                br#"{"id":1,"cmd":"x","params":{"a":1,"a":2}}"#,
                "a",
                "params",
            ),
            (
                br#"{"id":1,"cmd":"x","params":{"a":[{"b":1,"\u0062":2}]}}"#,
                "b",
                "params.a[0]",
            ),
            (br#"{"id":{"k":1,"k":2},"cmd":"x"}"#, "k", "id"),
        ] {
            let (_, e) = refused(line);
            assert_eq!(e.kind, ApiErrorKind::BadRequest);
            assert_eq!(&*e.message, format!("duplicate key {key:?} in {at}"));
        }
        // The id is echoed when the duplicate is elsewhere.
        let (id, _) = refused(br#"{"id":"x","cmd":"s","params":{"a":1,"a":2}}"#);
        assert_eq!(id, "\"x\"");
    }

    #[test]
    fn other_bad_lines() {
        let (_, e) = refused(b"{\"cmd\":\"st\xffatus\"}");
        assert!(e.message.starts_with("not UTF-8"), "{}", e.message);
        let (_, e) = refused(b"[1]");
        assert_eq!(e.kind, ApiErrorKind::BadRequest);
        let (id, e) = refused(br#"{"id":2,"cmd":7}"#);
        assert_eq!((id.as_str(), &*e.message), ("2", "no \"cmd\" string"));
        let (_, e) = refused(br#"{"id":2,"cmd":"chirp","params":{"duration_s":1e400}}"#);
        assert_eq!(e.kind, ApiErrorKind::BadParams);
        let deep = format!(
            "{{\"cmd\":\"s\",\"id\":{}1{}}}",
            "[".repeat(super::super::MAX_JSON_DEPTH + 1),
            "]".repeat(super::super::MAX_JSON_DEPTH + 1)
        );
        let (_, e) = refused(deep.as_bytes());
        assert!(e.message.contains("nested deeper"), "{}", e.message);
    }
}
