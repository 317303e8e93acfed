//! Every job kind of the CLI runs through the daemon's socket (`--daemon`,
//! and `bench campaign run --daemon`) with the same results as the local
//! run: `fit` (a CSV and a recording, with and without `--update`, and
//! `--frequencies`), `analyze`, `map` (with measured verdicts and the cells
//! CSV, and `--veering`), a small campaign, `export`, `recover` and
//! `upload`. Compared: the `--json`
//! summaries without the output paths (the daemon names its own outputs in
//! its recordings directory) and the outputs' contents (PNGs, CSVs, the
//! updated bench without its time-stamped first line, the campaign's
//! `cells.csv`, each cell's FRF and plot, the map). The daemon refuses what
//! the CLI refuses, naming the same parameter.

use crate::common;
use crate::daemon_fixtures;

use common::*;
use daemon_fixtures::*;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Output;

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn ok(o: &Output, what: &str) {
    assert!(
        o.status.success(),
        "{what}: exit {:?}\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// `bench ARGS --json`, successful, and its summary.
fn summary(args: &[&str], what: &str) -> Value {
    let mut all = args.to_vec();
    all.push("--json");
    let o = run(&all);
    ok(&o, what);
    json_stdout(&o)
}

/// `v` without the keys `paths` (at the top level), for comparing a local
/// summary with the daemon's.
fn without(v: &Value, paths: &[&str]) -> Value {
    let mut v = v.clone();
    for p in paths {
        v.as_object_mut().unwrap().remove(*p);
    }
    v
}

fn path_of(v: &Value, key: &str) -> PathBuf {
    PathBuf::from(v[key].as_str().unwrap_or_else(|| panic!("no {key} in {v}")))
}

fn same_file(a: &Path, b: &Path) {
    let (x, y) = (std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
    assert!(
        x == y,
        "{} and {} differ ({} and {} bytes)",
        a.display(),
        b.display(),
        x.len(),
        y.len()
    );
}

/// Every message of a recording: topic, log time, sequence and data.
fn messages(p: &Path) -> Vec<(String, u64, u32, Vec<u8>)> {
    let bytes = std::fs::read(p).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            (
                m.channel.topic.clone(),
                m.log_time,
                m.sequence,
                m.data.to_vec(),
            )
        })
        .collect()
}

/// A text file without its first line (the updated bench's header line
/// carries the time it was written).
fn after_first_line(p: &Path) -> String {
    let t = std::fs::read_to_string(p).unwrap();
    t.split_once('\n')
        .map_or(String::new(), |(_, r)| r.to_string())
}

#[test]
fn fit_analyze_map_and_a_campaign_through_the_daemon_equal_the_local_runs() {
    let d = Daemon::start();
    let sock = d.sock();
    let sock = sock.as_str();
    let dir = d.dir.path().to_path_buf();
    let cfg = d.config.to_str().unwrap();
    let at = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let in_recordings = |p: &Path| assert!(p.starts_with(dir.join("rec")), "{}", p.display());

    // An FRF to fit: a short local chirp of the daemon's bench.
    let mcap = at("c.mcap");
    let chirp = summary(
        &[
            "chirp",
            "--config",
            cfg,
            "--duration-s",
            "4",
            "--f-start-hz",
            "5",
            "--f-end-hz",
            "300",
            "--seed",
            "3",
            "--out",
            &mcap,
        ],
        "chirp",
    );
    let csv = path_of(&chirp, "frf_csv").to_str().unwrap().to_string();
    let csv = csv.as_str();

    // fit: a CSV, and a recording with its recorded config; each with and
    // without --update.
    for (input, update) in [(csv, false), (csv, true), (mcap.as_str(), true)] {
        let what = format!("fit {input} (update {update})");
        let png = at(&format!("local-{update}.fit.png"));
        let out = at(&format!("local-{update}.updated.toml"));
        let mut local = vec!["fit", input, "--png", png.as_str()];
        let mut remote = vec!["fit", input, "--daemon", sock];
        if update {
            local.extend(["--update", "--out", out.as_str(), "--overwrite"]);
            remote.push("--update");
        }
        // The recording's fit also exports its model (a MATLAB script).
        let model = at("local_model.m");
        if input == mcap.as_str() {
            let export = ["--export-model", "ss", "--model-format", "matlab"];
            local.extend(export);
            local.extend(["--model-out", model.as_str()]);
            remote.extend(export);
        }
        let (l, r) = (summary(&local, &what), summary(&remote, &what));
        if input == mcap.as_str() {
            in_recordings(&path_of(&r, "model"));
            same_file(&path_of(&l, "model"), &path_of(&r, "model"));
        }
        let paths = ["plot", "updated_config", "model"];
        assert_eq!(without(&l, &paths), without(&r, &paths), "{what}");
        assert!(l["fit"].is_object(), "{what}: no fit in {l}");
        in_recordings(&path_of(&r, "plot"));
        same_file(&path_of(&l, "plot"), &path_of(&r, "plot"));
        if update {
            in_recordings(&path_of(&r, "updated_config"));
            assert_eq!(
                after_first_line(&path_of(&l, "updated_config")),
                after_first_line(&path_of(&r, "updated_config")),
                "{what}"
            );
        }
        std::fs::remove_file(path_of(&l, "plot")).unwrap();
    }
    // An update to natural frequencies: nothing written, the same answer.
    let freq = [
        "fit",
        "--frequencies",
        "18.2,27.6,153.2,154.3",
        "--config",
        cfg,
    ];
    let l = summary(&freq, "fit --frequencies");
    let r = summary(
        &[&freq[..], &["--daemon", sock]].concat(),
        "fit --frequencies",
    );
    assert_eq!(l, r);

    // analyze: the same summary and the same two plots; the human form
    // too, but for the PNG lines.
    let point = [
        "analyze",
        "--config",
        cfg,
        "--operating-point-pct",
        "6",
        "--mass-asymmetry-pct",
        "4",
    ];
    let (pz, modes) = (at("pz.png"), at("modes.png"));
    let l = summary(
        &[
            &point[..],
            &[
                "--pole-zero-png",
                pz.as_str(),
                "--modes-png",
                modes.as_str(),
            ],
        ]
        .concat(),
        "analyze",
    );
    let r = summary(&[&point[..], &["--daemon", sock]].concat(), "analyze");
    let pngs = ["pole_zero_png", "modes_png"];
    assert_eq!(without(&l, &pngs), without(&r, &pngs));
    for k in pngs {
        in_recordings(&path_of(&r, k));
        same_file(&path_of(&l, k), &path_of(&r, k));
    }
    let text = |o: Output| {
        ok(&o, "analyze");
        String::from_utf8(o.stdout)
            .unwrap()
            .lines()
            .filter(|l| !l.contains(".png"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(
        text(run(&[&point[..], &["--no-plot"]].concat())),
        text(run(&[&point[..], &["--no-plot", "--daemon", sock]].concat()))
    );

    // map: measured verdicts judged against the model, the cells CSV.
    let measured = at("measured.csv");
    std::fs::write(
        &measured,
        "operating_point_m,mass_asymmetry,verdict\n0.001,0.02,true\n0.003,-0.05,false\n0.004,0.08,\n0.002,0.1,true\n",
    )
    .unwrap();
    let grid = [
        "map",
        "--config",
        cfg,
        "--operating-points",
        "21",
        "--mass-asymmetries",
        "11",
        "--measured",
        measured.as_str(),
    ];
    let (map_png, cells_csv) = (at("map.png"), at("cells.csv"));
    let l = summary(
        &[
            &grid[..],
            &["--png", map_png.as_str(), "--csv", cells_csv.as_str()],
        ]
        .concat(),
        "map",
    );
    let r = summary(&[&grid[..], &["--csv", "--daemon", sock]].concat(), "map");
    assert_eq!(without(&l, &["png", "csv"]), without(&r, &["png", "csv"]));
    assert!(
        !l["disagreements"].as_array().unwrap().is_empty(),
        "the measured verdicts are to disagree somewhere: {l}"
    );
    for k in ["png", "csv"] {
        in_recordings(&path_of(&r, k));
        same_file(&path_of(&l, k), &path_of(&r, k));
    }
    let veering = [
        "map",
        "--config",
        cfg,
        "--veering",
        "--operating-points",
        "31",
        "--localisation-at-pct",
        "2,6",
    ];
    let veer_png = at("veer.png");
    let l = summary(
        &[&veering[..], &["--png", veer_png.as_str()]].concat(),
        "veering",
    );
    let r = summary(&[&veering[..], &["--daemon", sock]].concat(), "veering");
    assert_eq!(without(&l, &["png"]), without(&r, &["png"]));
    same_file(&path_of(&l, "png"), &path_of(&r, "png"));

    // A campaign of four cells, run here and as one job of the daemon.
    let campaign = at("small.toml");
    std::fs::write(
        &campaign,
        format!(
            "config = {cfg:?}\nseed = 26\nsettle_s = 0.0\nmass_increment_kg = 0.0005\n\
             [grid]\noperating_point_pct = [3.6, 6.6]\nmass_asymmetry = [-0.05, 0.1]\n\
             [chirp]\nduration_s = 2.0\nf_start_hz = 5.0\nf_end_hz = 200.0\n"
        ),
    )
    .unwrap();
    let run_args = ["campaign", "run", campaign.as_str(), "--threads", "2"];
    let camp = at("camp");
    let l = summary(
        &[&run_args[..], &["--out", camp.as_str()]].concat(),
        "campaign",
    );
    let r = summary(&[&run_args[..], &["--daemon", sock]].concat(), "campaign");
    let paths = ["dir", "cells_csv", "map_png"];
    assert_eq!(without(&l, &paths), without(&r, &paths));
    assert_eq!(l["done"], 4, "{l}");
    let (ld, rd) = (path_of(&l, "dir"), path_of(&r, "dir"));
    in_recordings(&rd);
    for f in ["cells.csv", "map.png"] {
        same_file(&ld.join(f), &rd.join(f));
    }
    for cell in 0..4 {
        for f in ["frf.csv", "bode.png"] {
            let name = format!("cells/{cell:03}/{f}");
            same_file(&ld.join(&name), &rd.join(&name));
        }
    }

    // The same refusals, naming the same parameter: the CLI's flag, the
    // daemon's param, and the same reason after it.
    for (args, flag, param) in [
        (
            vec!["map", "--operating-points", "1"],
            "--operating-points",
            "operating_points",
        ),
        (
            vec!["analyze", "--operating-point-pct", "25", "--no-plot"],
            "--operating-point-pct 25",
            "operating_point_pct 25",
        ),
        (
            vec!["fit", csv, "--free", "nope", "--update"],
            "--free \"nope\"",
            "free \"nope\"",
        ),
    ] {
        let local = run(&args);
        let remote = run(&[&args[..], &["--daemon", sock]].concat());
        for o in [&local, &remote] {
            assert_eq!(o.status.code(), Some(2), "{args:?}: {o:?}");
        }
        let (le, re) = (
            String::from_utf8_lossy(&local.stderr).to_string(),
            String::from_utf8_lossy(&remote.stderr).to_string(),
        );
        let reason = le
            .split_once(&format!("error: {flag}: "))
            .unwrap_or_else(|| panic!("{args:?}: {le}"))
            .1
            .trim()
            .to_string();
        assert!(
            re.contains(&format!("params.{param}: {reason}")),
            "{args:?}: local {le:?}, daemon {re:?}"
        );
    }

    // Through the socket: a relative path is refused, the job slot is free
    // again after every job, and the stage was never touched.
    let mut c = d.client();
    let r = c.call("fit", json!({ "input": "c.frf.csv" }));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .starts_with("params.input: c.frf.csv is not an absolute path"),
        "{r}"
    );
    let s = c.call("status", json!({}));
    assert_eq!(s["result"]["state"], "disabled", "{s}");
    assert_eq!(s["result"]["job"], Value::Null, "{s}");
    assert_eq!(s["result"]["last_recording"], Value::Null, "{s}");
}

/// `bench export`, `recover` and `upload` run through the daemon
/// (`--daemon`) with the local runs' results: the same summaries but for
/// the paths the daemon names in its recordings directory, the same table
/// byte for byte, the same messages in the recovered recording, the same exit status for a
/// recovery that lost data (7), and the same objects in a directory store.
/// The daemon refuses what the CLI refuses, naming the parameter.
#[test]
fn export_recover_and_upload_through_the_daemon_equal_the_local_runs() {
    let d = Daemon::start();
    let sock = d.sock();
    let sock = sock.as_str();
    let dir = d.dir.path().to_path_buf();
    let cfg = d.config.to_str().unwrap();
    let at = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let in_recordings = |p: &Path| assert!(p.starts_with(dir.join("rec")), "{}", p.display());
    let mcap = at("e.mcap");
    summary(
        &[
            "chirp",
            "--config",
            cfg,
            "--duration-s",
            "1",
            "--f-start-hz",
            "20",
            "--seed",
            "4",
            "--out",
            &mcap,
        ],
        "chirp",
    );

    // export: the samples as CSV and the FRF as Parquet.
    for (to, topic) in [("csv", "/bench/sample"), ("parquet", "/sysid/frf")] {
        let what = format!("export {topic} to {to}");
        let out = at(&format!("local.{to}"));
        let args = ["export", mcap.as_str(), "--to", to, "--topic", topic];
        let l = summary(&[&args[..], &["--out", &out]].concat(), &what);
        let r = summary(&[&args[..], &["--daemon", sock]].concat(), &what);
        assert_eq!(without(&l, &["out"]), without(&r, &["out"]), "{what}");
        assert!(l["rows"].as_u64().unwrap() > 10, "{what}: {l}");
        in_recordings(&path_of(&r, "out"));
        same_file(&path_of(&l, "out"), &path_of(&r, "out"));
    }

    // recover: a killed run's .part (the last chunk cut), then one with
    // damaged chunks too, which loses data (exit 7) both ways.
    let bytes = std::fs::read(&mcap).unwrap();
    let cut = &bytes[..bytes.len() * 2 / 3];
    let mut damaged = cut.to_vec();
    for i in 0..16 {
        let k = damaged.len() / 3 + i * damaged.len() / 64;
        damaged[k] ^= 0x5a;
    }
    for (name, part, code) in [("cut", cut, 0), ("damaged", &damaged[..], 7)] {
        let what = format!("recover the {name} .part");
        let part_path = at(&format!("{name}.mcap.part"));
        std::fs::write(&part_path, part).unwrap();
        let local = run(&["recover", &part_path, "--json"]);
        let remote = run(&["recover", &part_path, "--daemon", sock, "--json"]);
        assert_eq!(
            local.status.code(),
            Some(code),
            "{what}: {}",
            stderr(&local)
        );
        assert_eq!(
            remote.status.code(),
            Some(code),
            "{what}: {}",
            stderr(&remote)
        );
        if code == 7 {
            assert!(stderr(&remote).contains("data lost"), "{}", stderr(&remote));
        }
        let (l, r) = (json_stdout(&local), json_stdout(&remote));
        assert_eq!(without(&l, &["to"]), without(&r, &["to"]), "{what}");
        in_recordings(&path_of(&r, "to"));
        // The same messages (the MCAP writer orders its summary's schemas
        // as its hash map does, so the files are not byte for byte alike).
        let (ml, mr) = (messages(&path_of(&l, "to")), messages(&path_of(&r, "to")));
        assert!(ml.len() > 100, "{what}: {} messages", ml.len());
        assert!(
            ml == mr,
            "{what}: {} and {} messages differ",
            ml.len(),
            mr.len()
        );
    }

    // upload: the recording, its companions and its row to two directory
    // stores; the same objects, the recording's byte for byte.
    let stores = [dir.join("store-local"), dir.join("store-daemon")];
    for s in &stores {
        std::fs::create_dir(s).unwrap();
    }
    let url = |s: &Path| format!("file://{}", s.display());
    let l = summary(&["upload", "--to", &url(&stores[0]), &mcap], "upload");
    let r = summary(
        &["upload", "--to", &url(&stores[1]), &mcap, "--daemon", sock],
        "upload",
    );
    let keys = |v: &Value| {
        let mut k: Vec<String> = v["confirmed"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["key"].as_str().unwrap().to_string())
            .collect();
        k.sort();
        k
    };
    assert_eq!(keys(&l), keys(&r));
    assert!(keys(&l).iter().any(|k| k.ends_with("e.mcap")), "{l}");
    same_file(&stores[0].join("e.mcap"), &stores[1].join("e.mcap"));

    // Refusals name the parameter, as the CLI names its argument.
    let mut c = d.client();
    let refused = |r: Value, field: &str| {
        assert_eq!(r["error"]["kind"], "bad_params", "{r}");
        let m = r["error"]["message"].as_str().unwrap().to_string();
        assert!(m.contains(&format!("params.{field}")), "{field}: {m}");
    };
    refused(
        c.call("export", json!({ "recording": "e.mcap", "to": "csv" })),
        "recording",
    );
    refused(
        c.call(
            "export",
            json!({ "recording": mcap, "to": "csv", "topic": "/no/such" }),
        ),
        "recording",
    );
    refused(
        c.call("export", json!({ "recording": mcap, "to": "xlsx" })),
        "to",
    );
    refused(
        c.call("recover", json!({ "part": at("none.mcap.part") })),
        "part",
    );
    refused(
        c.call("upload", json!({ "to": "ftp://x", "recordings": [mcap] })),
        "to",
    );
    refused(
        c.call(
            "upload",
            json!({ "to": url(&stores[1]), "recordings": ["e.mcap"] }),
        ),
        "recordings",
    );
    refused(
        c.call(
            "upload",
            json!({ "to": url(&stores[1]), "recordings": [mcap], "retry_for_s": -1.0 }),
        ),
        "retry_for_s",
    );
    // The local-only flags are refused with --daemon.
    let o = run(&[
        "export",
        &mcap,
        "--to",
        "csv",
        "--out",
        &at("x.csv"),
        "--daemon",
        sock,
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--out"), "{}", stderr(&o));
}

/// `--daemon` means one thing on every command: every job kind the daemon
/// takes ([`JobRequest::KINDS`]) is a command whose `--help` offers
/// `--daemon [SOCKET]`, and the daemon answers each kind (a request
/// without its required parameters is `bad_params`, never
/// `unknown_command`).
///
/// [`JobRequest::KINDS`]: bench::jobs::request::JobRequest::KINDS
#[test]
fn every_job_kind_is_a_command_with_daemon_and_a_daemon_job() {
    let d = Daemon::start();
    let mut c = d.client();
    let mut shared = std::collections::BTreeMap::new();
    for kind in bench::jobs::request::JobRequest::KINDS {
        let cmd: &[&str] = match kind {
            "campaign" => &["campaign", "run"],
            "plot" => &["plot", "bode"],
            k => &[k],
        };
        // `-h`: each flag's short help (`--help` gives a long help).
        let o = run(&[cmd, &["-h"]].concat());
        ok(&o, kind);
        let help = String::from_utf8_lossy(&o.stdout);
        assert!(help.contains("--daemon [<SOCKET>]"), "bench {kind}: {help}");
        // The shared flags are declared once: one short help each, on
        // every command (campaign run's --daemon says more in its long
        // help); --config on every job that reads a bench description.
        for flag in ["--json", "--daemon [<SOCKET>]", "--config <FILE>"] {
            // Its help on its line, or on the next when clap wraps.
            let lines: Vec<&str> = help.lines().collect();
            let Some(at) = lines.iter().position(|l| l.trim_start().starts_with(flag)) else {
                assert_eq!(flag, "--config <FILE>", "bench {kind}: no {flag}: {help}");
                continue;
            };
            let mut words: Vec<&str> = lines[at].split_whitespace().collect();
            if words.len() <= flag.split_whitespace().count() {
                words.extend(lines.get(at + 1).copied().unwrap_or("").split_whitespace());
            }
            let line = words.join(" ");
            let first = shared.entry(flag).or_insert_with(|| line.clone());
            assert_eq!(*first, line, "bench {kind}: {flag} is declared again");
        }
        let r = c.call(kind, json!({ "no_such_parameter": 1 }));
        assert_eq!(r["error"]["kind"], "bad_params", "{kind}: {r}");
    }
    assert_eq!(shared.len(), 3);
}
