//! The daemon's wire protocol: error kinds and responses, `status`,
//! events, and how a request's `params` become a job request. May use
//! `jobs::request` and `serde`; nothing here touches the bench.

use crate::error::RunError;
use crate::jobs::request::JobRequest;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

/// The kind of an error response: what the client may do about it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ApiErrorKind {
    /// Not JSON, or no `cmd`.
    BadRequest,
    /// No such command.
    UnknownCommand,
    /// A parameter is missing, unknown or out of its range.
    BadParams,
    /// A job is running.
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

/// An error response: `{"kind": KIND, "message": ".."}`.
#[derive(Debug, Clone, Serialize)]
pub(super) struct ApiError {
    pub(super) kind: ApiErrorKind,
    pub(super) message: String,
}

impl ApiError {
    pub(super) fn new(kind: ApiErrorKind, message: impl Into<String>) -> Self {
        Self {
            kind,
            message: message.into(),
        }
    }

    pub(super) fn from_run(e: &RunError) -> Self {
        Self::new(ApiErrorKind::of_run(e), format!("{e:#}"))
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
    pub(super) jobs_run: u64,
    pub(super) last_recording: Option<String>,
}

#[derive(Debug, Clone, Serialize)]
pub(super) struct JobStatus {
    pub(super) id: u64,
    pub(super) kind: &'static str,
    pub(super) ticks: u64,
    pub(super) total_ticks: u64,
    pub(super) recording: String,
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

/// The job request of a `chirp` or `control` command, and whether it asked
/// to `detach` (a transport option of the daemon, not part of the job).
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
    let request = if cmd == "chirp" {
        JobRequest::Chirp(from_params(params)?)
    } else {
        JobRequest::Control(from_params(params)?)
    };
    Ok((request, detach))
}

pub(super) fn respond(id: &Value, r: Result<Value, ApiError>) -> String {
    match r {
        Ok(v) => json!({ "id": id, "ok": true, "result": v }).to_string(),
        Err(e) => json!({ "id": id, "ok": false, "error": e }).to_string(),
    }
}
