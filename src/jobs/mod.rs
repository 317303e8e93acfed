//! Jobs: what a run does from request to summary. [`session`] runs any
//! [`crate::rt::Job`] on a stage into a recording; [`chirp`] and [`step`]
//! are the identification and closed-loop step jobs built on it.
//!
//! May use everything below it; never the CLI, the daemon or a campaign.
//!
//! Layer rule: may use `analysis`, `config`, `control`, `error`, `ident`, `outputs`, `plot`, `record`, `rt`, `vocab`.

pub mod chirp;
pub mod request;
pub mod session;
pub mod step;
