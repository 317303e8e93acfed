//! Jobs: what a run does from request to summary. [`session`] runs any
//! [`crate::rt::Job`] on a stage into a recording; [`chirp`] and [`step`]
//! are the identification and closed-loop step jobs built on it.
//!
//! May use everything below it (`rt`, `ident`, `control`, `record`, `plot`,
//! `config`); never the CLI or the daemon.

pub mod chirp;
pub mod point;
pub mod request;
pub mod session;
pub mod step;
