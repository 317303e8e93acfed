//! The tests that run external servers and clients beside `bench`:
//! Prometheus, an S3-compatible server (moto), DuckDB, socat, WebSocket
//! clients, and EtherCAT over a veth pair in network namespaces. One test
//! binary; what each needs is installed by `tests/run`.

#[path = "../common/mod.rs"]
mod common;
#[path = "../common/daemon.rs"]
mod daemon_fixtures;

mod catalogue;
mod daemon_socat;
mod ethercat;
mod live;
mod metrics;
mod upload;
