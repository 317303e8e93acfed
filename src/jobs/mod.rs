//! Jobs: what a run does from request to summary. Every workflow of the
//! CLI is a job here, behind the one [`request::JobRequest`] the daemon
//! takes: a request (serde, what the flags and the daemon's params say),
//! its options (the request with its output paths), a `run_*` function,
//! a summary.
//!
//! - [`session`] runs any [`crate::rt::Job`] on a stage into a recording;
//!   [`chirp`] and [`control`] are the identification and closed-loop step
//!   jobs built on it (`bench chirp`, `bench control`); [`verify`] is
//!   `bench control --verify`'s part of the step job (the injection
//!   planned and checked before enable, the loop measured after).
//! - [`fit`] (`bench fit`, with the model update), [`analyze`] (`bench
//!   analyze`) and [`map`] (`bench map`, with the measured-verdict CSV)
//!   compute from files and the model.
//! - [`plot`] (`bench plot bode|nyquist`) draws several FRFs on one
//!   figure, each fitted as [`fit`] fits it.
//! - A campaign's request is here ([`request::CampaignRequest`]); the
//!   campaign job itself is [`crate::campaign::job`].
//! - [`catalogue`]: the row every chirp and control run appends to the
//!   run catalogue, and `bench catalogue`, which rebuilds it from the
//!   recordings.
//! - [`export`] (`bench export`: a recording's channel as a table) and
//!   [`recover`] (`bench recover`: a killed run's `.part` file made
//!   whole) work on one recording; each plans its output for a
//!   [`crate::outputs::Destination`], the command line's or the daemon's.
//! - [`point`]: the operating point and asymmetry every job that takes
//!   one shares (% of L to metres, the range checks).
//!
//! May use everything below it; never the CLI, the daemon or a campaign.
//!
//! Layer rule: may use `analysis`, `catalogue`, `config`, `control`, `design`, `error`, `ident`, `input_file`, `outputs`, `plot`, `record`, `rt`, `track`, `vocab`.

pub mod analyze;
pub mod catalogue;
pub mod chirp;
pub mod control;
pub mod design;
pub mod export;
pub mod fit;
pub mod map;
pub mod plot;
pub mod point;
pub mod recover;
pub mod request;
pub mod session;
pub mod track;
pub mod track_request;
pub mod verify;

/// A config given by path that does not load, as a job's error: a file
/// refused as an input ([`crate::input_file`]: not a regular file, too
/// large) names its option, `config` (`--config`, the daemon's
/// `params.config`); any other error (missing, a syntax or key error)
/// is bad input, its text naming the file.
pub(crate) fn config_error(e: crate::config::ConfigError) -> crate::error::RunError {
    use crate::config::ConfigError;
    match e {
        ConfigError::NotAConfigFile { path, reason } => {
            crate::error::RunError::option("config", path.display(), reason)
        }
        e => crate::error::RunError::BadInput(e.to_string()),
    }
}
