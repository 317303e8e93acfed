//! `bench export`: a recording's samples, timing and FRF as CSV and
//! Parquet, checked value for value against the recording read back with
//! the MCAP reader; bad input.

use crate::common;

use bench::record::read_samples_tolerant;
use common::*;
use parquet::file::reader::{FileReader, SerializedFileReader};
use parquet::record::Field;
use std::path::Path;

fn short_chirp(dir: &Path) -> String {
    let rec = path_in(dir, "run.mcap");
    let out = run(&[
        "chirp",
        "--out",
        &rec,
        "--duration-s",
        "1",
        "--f-start-hz",
        "20",
        "--seed",
        "7",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    rec
}

/// `bench export REC --to csv --out CSV` (must succeed); the CSV's text.
fn export_csv(rec: &str, csv: &str) -> String {
    let out = run(&["export", rec, "--to", "csv", "--out", csv]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::read_to_string(csv).unwrap()
}

fn f64_of(s: &str) -> f64 {
    if s == "NaN" {
        f64::NAN
    } else {
        s.parse().unwrap()
    }
}

fn same(a: f64, b: f64) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

#[test]
fn samples_export_to_csv_and_parquet_equal_the_recording() {
    let dir = tmp();
    let rec = short_chirp(dir.path());
    let samples = read_samples_tolerant(&std::fs::read(&rec).unwrap());
    assert!(samples.len() > 5000);

    let text = export_csv(&rec, &path_in(dir.path(), "s.csv"));
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "log_time_ns,tick,t_s,wake_s,current_command_a,position_m,excitation_a,setpoint_m,state,out_of_range"
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), samples.len());
    for (r, s) in rows.iter().zip(&samples) {
        assert_eq!(r[1].parse::<u64>().unwrap(), s.tick);
        assert!(same(f64_of(r[2]), s.t_s));
        assert!(same(f64_of(r[4]), s.current_command_a));
        assert!(same(f64_of(r[5]), s.position_m), "{r:?} {s:?}");
        assert!(same(f64_of(r[6]), s.excitation_a));
        assert!(same(f64_of(r[7]), s.setpoint_m));
        assert_eq!(r[8], s.state.as_str());
        assert_eq!(r[9] == "true", s.out_of_range);
    }

    let pq = path_in(dir.path(), "s.parquet");
    let out = run(&["export", &rec, "--to", "parquet", "--out", &pq]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let reader = SerializedFileReader::new(std::fs::File::open(&pq).unwrap()).unwrap();
    assert_eq!(
        reader.metadata().file_metadata().num_rows() as usize,
        samples.len()
    );
    for (row, s) in reader.get_row_iter(None).unwrap().zip(&samples) {
        let row = row.unwrap();
        let cols: Vec<(&String, &Field)> = row.get_column_iter().collect();
        assert_eq!(cols[1], (&"tick".to_string(), &Field::Long(s.tick as i64)));
        let real = |i: usize| match cols[i].1 {
            Field::Double(x) => *x,
            other => panic!("{other:?}"),
        };
        assert!(same(real(5), s.position_m));
        assert!(same(real(4), s.current_command_a));
        assert_eq!(cols[8].1, &Field::Str(s.state.as_str().to_string()));
        assert_eq!(cols[9].1, &Field::Bool(s.out_of_range));
    }
}

/// Issue 29, results that travel: the FRF exported as CSV is the FRF CSV
/// of `bench chirp` (the same header and lines), so `bench fit` reads it
/// and fits what it fits from the recording; as Parquet it is the generic
/// table, one row per line, equal to the CSV's numbers.
#[test]
fn the_frf_exports_as_the_frf_csv_that_fit_reads() {
    let dir = tmp();
    let rec = short_chirp(dir.path());
    let out = run(&["export", &rec, "--to", "csv", "--topic", "/sysid/frf"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let exported_path = dir.path().join("run.sysid-frf.csv");
    let exported = std::fs::read_to_string(&exported_path).unwrap();
    let frf_csv = std::fs::read_to_string(dir.path().join("run.frf.csv")).unwrap();
    assert_eq!(exported.lines().next(), Some(bench::ident::frf::CSV_HEADER));
    assert_eq!(exported, frf_csv, "the export is the chirp's FRF CSV");
    // bench fit: the exported CSV and the recording give the same modes
    // and the same exit status (this short sweep's fit may be flagged,
    // exit 9: then both are).
    let fit = |input: &str| {
        let o = run(&["fit", input, "--no-plot", "--json"]);
        assert!(
            matches!(o.status.code(), Some(0 | 9)),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        (o.status.code(), json_stdout(&o)["modes"].clone())
    };
    let ((ca, a), (cb, b)) = (fit(exported_path.to_str().unwrap()), fit(&rec));
    assert_eq!(ca, cb);
    assert!(a.as_array().is_some_and(|m| !m.is_empty()), "{a}");
    let freqs = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|m| m["frequency_hz"].as_f64().unwrap())
            .collect()
    };
    for (x, y) in freqs(&a).iter().zip(freqs(&b)) {
        // The CSV holds 7 significant digits of the recorded lines.
        assert!((x - y).abs() < 1e-5 * y, "{a} against {b}");
    }
    assert_eq!(freqs(&a).len(), freqs(&b).len());
    // Parquet: the generic table of the same lines.
    let out = run(&["export", &rec, "--to", "parquet", "--topic", "/sysid/frf"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows = String::from_utf8_lossy(&out.stdout).into_owned();
    let n = frf_csv.lines().count() - 1;
    assert!(
        rows.starts_with(&format!("{n} rows of /sysid/frf")),
        "{rows}"
    );
    // Timing and events export too.
    for topic in ["/bench/timing", "/bench/event"] {
        let out = run(&["export", &rec, "--to", "parquet", "--topic", topic]);
        assert!(
            out.status.success(),
            "{topic}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

#[test]
fn bad_export_input_exits_2_naming_the_file_or_topic() {
    let dir = tmp();
    let rec = short_chirp(dir.path());
    let out = run(&["export", &rec, "--to", "csv", "--topic", "/no/such"]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/no/such") && err.contains("/bench/sample"),
        "{err}"
    );
    let junk = path_in(dir.path(), "junk.mcap");
    std::fs::write(&junk, b"not an mcap file at all").unwrap();
    let out = run(&["export", &junk, "--to", "csv"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("junk.mcap"));
    let out = run(&[
        "export",
        &path_in(dir.path(), "missing.mcap"),
        "--to",
        "csv",
    ]);
    assert_eq!(out.status.code(), Some(2));
    // An existing output is kept unless --overwrite.
    let csv = path_in(dir.path(), "keep.csv");
    std::fs::write(&csv, "keep").unwrap();
    let out = run(&["export", &rec, "--to", "csv", "--out", &csv]);
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(std::fs::read_to_string(&csv).unwrap(), "keep");
    let out = run(&["export", &rec, "--to", "csv", "--out", &csv, "--overwrite"]);
    assert!(out.status.success());
    assert!(std::fs::read_to_string(&csv)
        .unwrap()
        .starts_with("log_time_ns,"));
    let out = run(&["export", &rec, "--to", "xlsx"]);
    assert_eq!(out.status.code(), Some(2));
}

/// A recording made before the protobuf blocks (`tests/data/README.md`:
/// one JSON `bench.Sample` per tick, lz4 chunks) still reads: the samples
/// through `read_samples_tolerant`, and `bench export` gives one row per
/// tick equal, value for value, to the JSON messages parsed here with
/// serde_json alone.
#[test]
fn recordings_made_before_the_blocks_still_read_and_export() {
    let legacy = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/legacy-json-samples.mcap");
    let bytes = std::fs::read(&legacy).unwrap();
    let json: Vec<(u64, serde_json::Value)> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| m.channel.topic == "/bench/sample")
        .map(|m| {
            assert_eq!(m.channel.message_encoding, "json");
            (m.log_time, serde_json::from_slice(&m.data).unwrap())
        })
        .collect();
    assert_eq!(json.len(), 2000);
    let samples = read_samples_tolerant(&bytes);
    assert_eq!(samples.len(), json.len());
    let num = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    for (s, (_, v)) in samples.iter().zip(&json) {
        assert_eq!(s.tick, v["tick"].as_u64().unwrap());
        assert!(same(s.position_m, num(&v["position_m"])));
        assert!(same(s.current_command_a, num(&v["current_command_a"])));
    }
    let dir = tmp();
    let text = export_csv(legacy.to_str().unwrap(), &path_in(dir.path(), "legacy.csv"));
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), json.len());
    for (r, (log_time, v)) in rows.iter().zip(&json) {
        assert_eq!(r[col("log_time_ns")].parse::<u64>().unwrap(), *log_time);
        assert_eq!(
            r[col("tick")].parse::<u64>().unwrap(),
            v["tick"].as_u64().unwrap()
        );
        for f in ["t_s", "position_m", "current_command_a", "setpoint_m"] {
            assert!(same(f64_of(r[col(f)]), num(&v[f])), "{f}");
        }
        assert_eq!(r[col("state")], v["state"].as_str().unwrap());
    }
}
