//! `bench campaign`: the thesis' Fig 5-10 experiment over a grid of
//! operating point × mass asymmetry, one chirp and one verdict per cell,
//! resumable after a crash.
//!
//! - [`file`]: the campaign file (bench config, grid, chirp overrides,
//!   settle time, trim mass), its validation, the cells, the operator's
//!   serpentine order and the per-cell seeds.
//! - [`run`]: the campaign directory, the cells (in parallel on the
//!   simulator, or attended on hardware), the results.
//! - [`job`]: a campaign started or resumed and run, as the CLI and the
//!   daemon's `campaign` job do it.
//! - [`disk`]: the disk a campaign will use, estimated before it starts.
//! - [`journal`]: the append-only, fsync'd, checksummed journal that makes
//!   a campaign survive SIGKILL and power loss without losing a completed
//!   cell or counting a half-finished one.
//!
//! Layer rule: may use `analysis`, `catalogue`, `config`, `design`, `error`, `ident`, `input_file`, `job_memory`, `jobs`, `outputs`, `plot`, `rt`, `splitmix`.

pub mod disk;
pub mod file;
pub mod job;
pub mod journal;
pub mod run;
