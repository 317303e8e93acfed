//! The recorder's cost per tick and the recording's size per tick on the
//! default chirp (issue 16: at most 0.3 µs of CPU and 32 bytes on disk per
//! tick for `/bench/sample`).
//!
//! Setup runs the default `bench chirp` once in virtual time and reads its
//! samples back; the benchmark writes those samples again through a
//! [`Recorder`] as the writer thread does and finishes the file: with the
//! real-time chunk policy (a chunk every 250 ticks, 50 ms of loop time at
//! 5 kHz) and with the virtual-time one (every 5 000 ticks, 1 s). The
//! writer runs on one thread, so the wall time per tick is its CPU time per
//! tick. The sizes (whole file and per tick) are printed once.

mod common;

use bench::outputs::Existing;
use bench::record::topics::{Record, SampleRecord};
use bench::record::{read_samples_tolerant, Recorder};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::path::Path;
use std::time::Duration;

/// The default chirp's samples (as recorded).
fn default_chirp_samples(dir: &Path) -> (Vec<SampleRecord>, u64) {
    let opts = common::default_chirp(dir);
    common::run(&opts);
    let bytes = std::fs::read(&opts.out).unwrap();
    (read_samples_tolerant(&bytes), bytes.len() as u64)
}

/// Writes `samples` into a new recording at `path` as the writer thread
/// does, a chunk every `chunk_ticks`; returns the file's size, bytes.
fn record(path: &Path, samples: &[SampleRecord], chunk_ticks: usize) -> u64 {
    let mut rec = Recorder::create_with(path, Existing::Replace, None).unwrap();
    for (i, s) in samples.iter().enumerate() {
        rec.write_record(&Record::Sample(*s)).unwrap();
        if i % chunk_ticks == chunk_ticks - 1 {
            rec.flush_chunk().unwrap();
        }
    }
    let out = rec.finish().unwrap();
    std::fs::metadata(out).unwrap().len()
}

fn recorder(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let (samples, chirp_bytes) = default_chirp_samples(dir.path());
    let n = samples.len() as f64;
    let path = dir.path().join("samples.mcap");
    // The chunk policies in ticks at the default 5 kHz.
    let policies = [("real_time", 250), ("virtual_time", 5000)];
    for (name, chunk_ticks) in policies {
        let sample_bytes = record(&path, &samples, chunk_ticks);
        eprintln!(
            "default chirp, {name} chunks ({chunk_ticks} ticks): {} ticks; the samples \
             alone (/bench/sample blocks, /bench/envelope, headers, index): {} bytes \
             = {:.1} B/tick",
            samples.len(),
            sample_bytes,
            sample_bytes as f64 / n,
        );
    }
    eprintln!(
        "the whole chirp recording (virtual time): {} bytes = {:.1} B/tick",
        chirp_bytes,
        chirp_bytes as f64 / n
    );
    let mut g = c.benchmark_group("recorder");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.throughput(Throughput::Elements(samples.len() as u64));
    for (name, chunk_ticks) in policies {
        g.bench_function(format!("default_chirp_samples_{name}"), |b| {
            b.iter(|| record(&path, &samples, chunk_ticks))
        });
    }
    g.finish();
}

criterion_group!(benches, recorder);
criterion_main!(benches);
