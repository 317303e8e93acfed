//! `bench plot bode|nyquist` end to end: recordings and CSVs of chirps at
//! other operating points, asymmetries, seeds and frequency grids, and a
//! small campaign's cells, overlaid; each trace's fit and verdict equal
//! what `bench fit` gives for that input, and the verdicts what the model
//! (`bench analyze`) says of each bench; each trace's colour in the
//! figure; the pair window by its documented rule from `bench fit`'s
//! pairs; the daemon's `plot` job; and bad input, generated, each refused
//! with exit 2 naming the argument and nothing written.

use crate::common;
use crate::daemon_fixtures;

use common::*;
use daemon_fixtures::*;
use image::RgbImage;
use serde_json::{json, Value};
use std::path::Path;

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `bench chirp --out DIR/NAME.mcap ARGS --json`: the recording.
fn chirp(dir: &Path, name: &str, args: &[&str]) -> String {
    let mcap = path_in(dir, &format!("{name}.mcap"));
    let mut a = vec!["chirp", "--out", &mcap, "--json"];
    a.extend_from_slice(args);
    let o = run(&a);
    assert!(o.status.success(), "{}", stderr(&o));
    mcap
}

/// `bench fit INPUT --no-plot --json [--config C]` (a flagged fit exits 9
/// with its JSON).
fn fit(input: &str, config: Option<&str>) -> Value {
    let mut a = vec!["fit", input, "--no-plot", "--json"];
    if let Some(c) = config {
        a.extend(["--config", c]);
    }
    let o = run(&a);
    assert!(
        matches!(o.status.code(), Some(0 | 9)),
        "{input}: {}",
        stderr(&o)
    );
    json_stdout(&o)
}

/// The model's damped CMP-CNMP answer for the built-in bench with `args`
/// (`bench analyze`).
fn model_cnmp(args: &[&str]) -> bool {
    let mut a = vec!["analyze", "--no-plot", "--json"];
    a.extend_from_slice(args);
    let o = run(&a);
    assert!(o.status.success(), "{}", stderr(&o));
    json_stdout(&o)["cnmp_damped"].as_bool().unwrap()
}

/// The trace's fit and verdict are `bench fit`'s, and its legend shows the
/// answer and the net phase as `bench fit` prints them.
fn assert_as_fit(trace: &Value, fit: &Value) {
    let label = trace["label"].as_str().unwrap();
    assert_eq!(trace["fit"], fit["fit"], "{label}: fit");
    assert_eq!(trace["verdict"], fit["verdict"], "{label}: verdict");
    let legend = trace["legend"].as_str().unwrap();
    let answer = match fit["verdict"]["cmp_cnmp"].as_bool() {
        Some(true) => "CMP-CNMP zeros",
        Some(false) => "no CMP-CNMP zeros",
        None => "undecided",
    };
    assert!(legend.starts_with(&format!("{label}: ")), "{legend}");
    assert!(legend.contains(answer), "{legend}");
    if let Some(p) = fit["verdict"]["phase_test"]["pair"].as_object() {
        let net = format!("net phase {:.0}°", p["net_phase_deg"].as_f64().unwrap());
        assert!(legend.contains(&net), "{legend} lacks {net}");
    }
    match fit["verdict"]["reason"].as_str() {
        Some(r) => assert!(legend.contains(r), "{legend} lacks the reason {r}"),
        None => assert!(legend.contains("both tests"), "{legend}"),
    }
}

/// The pair window by the rule `bench plot` documents (the Bode figure's:
/// `lower − d … upper + d`, `d = max(upper − lower, 1 % of lower)`, the
/// union over the inputs), from `bench fit`'s pairs.
fn pair_window(fits: &[Value]) -> Option<[f64; 2]> {
    fits.iter()
        .filter_map(|f| f["verdict"]["phase_test"]["pair"].as_object())
        .map(|p| {
            let (lo, hi) = (
                p["lower_hz"].as_f64().unwrap(),
                p["upper_hz"].as_f64().unwrap(),
            );
            let d = (hi - lo).max(0.01 * lo);
            [lo - d, hi + d]
        })
        .reduce(|a, b| [a[0].min(b[0]), a[1].max(b[1])])
}

/// `#rrggbb` as RGB.
fn rgb(hex: &str) -> [u8; 3] {
    let v = |i: usize| u8::from_str_radix(&hex[i..i + 2], 16).unwrap();
    [v(1), v(3), v(5)]
}

/// The frames (black rectangles) in columns `x0..x1`: `(left, right, top,
/// bottom)`, top to bottom.
fn frames(img: &RgbImage, x0: u32, x1: u32) -> Vec<(u32, u32, u32, u32)> {
    let mut edges: Vec<(u32, u32, u32)> = Vec::new();
    for y in 0..img.height() {
        let (mut best, mut start, mut span) = (0, None, (0, 0));
        for x in x0..=x1 {
            let black = x < x1 && img.get_pixel(x, y).0 == [0, 0, 0];
            match (black, start) {
                (true, None) => start = Some(x),
                (false, Some(s)) => {
                    if x - s > best {
                        best = x - s;
                        span = (s, x - 1);
                    }
                    start = None;
                }
                _ => {}
            }
        }
        if best >= (x1 - x0) / 2 && edges.last().is_none_or(|e| y > e.0 + 2) {
            edges.push((y, span.0, span.1));
        }
    }
    assert!(
        edges.len().is_multiple_of(2),
        "unpaired frame edges {edges:?}"
    );
    edges
        .chunks(2)
        .map(|p| (p[0].1, p[0].2, p[0].0, p[1].0))
        .collect()
}

/// Pixels of colour `c` (±3 per channel) strictly inside a frame.
fn pixels_of(img: &RgbImage, f: (u32, u32, u32, u32), c: [u8; 3]) -> usize {
    let mut n = 0;
    for y in f.2 + 1..f.3 {
        for x in f.0 + 1..f.1 {
            let p = img.get_pixel(x, y).0;
            if (0..3).all(|k| (i32::from(p[k]) - i32::from(c[k])).abs() <= 3) {
                n += 1;
            }
        }
    }
    n
}

/// Three chirps on the simulated Chapter 5 bench: the default (8 % of L,
/// +10 %), one at 4 % of L (seed 2) swept over 1–300 Hz only (another
/// grid), one at −10 % asymmetry exported as a CSV by `bench export`.
/// Overlaid as Bode and as Nyquist: a trace per input in input order,
/// each fit and verdict `bench fit`'s, each verdict the model's, the pair
/// window from `bench fit`'s pairs, each colour in the panels.
#[test]
fn recordings_and_csvs_are_overlaid_each_with_its_fits_verdict() {
    let dir = tmp();
    let d = dir.path();
    let a = chirp(d, "a", &[]);
    let b = chirp(
        d,
        "b",
        &[
            "--operating-point-pct",
            "4",
            "--seed",
            "2",
            "--f-start-hz",
            "1",
            "--f-end-hz",
            "300",
        ],
    );
    let c_mcap = chirp(d, "c", &["--mass-asymmetry", "-0.1"]);
    let c = path_in(d, "c.csv");
    let o = run(&[
        "export",
        &c_mcap,
        "--topic",
        "/sysid/frf",
        "--to",
        "csv",
        "--out",
        &c,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let inputs = [a.as_str(), b.as_str(), c.as_str()];
    let fits: Vec<Value> = inputs.iter().map(|i| fit(i, None)).collect();
    let models = [
        model_cnmp(&[]),
        model_cnmp(&["--operating-point-pct", "4"]),
        model_cnmp(&["--mass-asymmetry", "-0.1"]),
    ];
    for kind in ["bode", "nyquist"] {
        let out = path_in(d, &format!("{kind}.png"));
        let before = listing(d);
        let mut args = vec!["plot", kind];
        args.extend(inputs);
        args.extend(["--out", &out, "--json"]);
        let o = run(&args);
        assert_eq!(o.status.code(), Some(0), "{kind}: {}", stderr(&o));
        let s = json_stdout(&o);
        assert_eq!(s["kind"], kind);
        assert_eq!(s["plot"], out.as_str());
        let mut after = before.clone();
        after.push(format!("{kind}.png"));
        after.sort();
        assert_eq!(listing(d), after, "only the figure is written");
        let traces = s["traces"].as_array().unwrap();
        assert_eq!(traces.len(), 3);
        for (i, t) in traces.iter().enumerate() {
            assert_eq!(t["input"], inputs[i]);
            assert_as_fit(t, &fits[i]);
            assert_eq!(
                t["verdict"]["cmp_cnmp"].as_bool(),
                Some(models[i]),
                "{kind} {}: the model says {}",
                inputs[i],
                models[i]
            );
        }
        // Each its own grid: b stops at 300 Hz, the band is everyone's.
        assert_eq!(traces[1]["band_hz"][1], 300.0);
        assert_eq!(s["band_hz"], json!([0.1, 500.0]));
        let want = pair_window(&fits).unwrap();
        let got = &s["pair_zoom_hz"];
        for k in 0..2 {
            assert!(
                (got[k].as_f64().unwrap() - want[k]).abs() < 1e-9,
                "{got} against {want:?}"
            );
        }
        // The model: the first recording's bench.
        assert_eq!(s["model"]["config"], format!("recorded in {a}"));

        let img = image::open(&out).unwrap().to_rgb8();
        let colors: Vec<[u8; 3]> = traces
            .iter()
            .map(|t| rgb(t["color"].as_str().unwrap()))
            .collect();
        assert!(colors[0] != colors[1] && colors[1] != colors[2] && colors[0] != colors[2]);
        // The panels holding every trace: Bode's magnitude, phase and the
        // two zoom panels; Nyquist's whole band and pairs' band.
        let panels: Vec<(u32, u32, u32, u32)> = if kind == "bode" {
            let fr = frames(&img, 0, 1400);
            assert_eq!(fr.len(), 5, "{fr:?}");
            vec![fr[0], fr[1], fr[3], fr[4]]
        } else {
            let (l, r) = (frames(&img, 0, 700), frames(&img, 700, 1400));
            assert_eq!((l.len(), r.len()), (1, 1), "{l:?} {r:?}");
            vec![l[0], r[0]]
        };
        for (p, f) in panels.iter().enumerate() {
            for (i, col) in colors.iter().enumerate() {
                let n = pixels_of(&img, *f, *col);
                assert!(n > 30, "{kind} panel {p}: {n} pixels of trace {i} {col:?}");
            }
        }
    }
}

/// A campaign file `c.toml` in `dir` of the shipped Chapter 5 bench, its
/// amplifier's bandwidth `amplifier_hz`, at +10 % asymmetry over
/// `operating_points_pct`.
fn campaign_file(
    dir: &Path,
    seed: u64,
    operating_points_pct: &str,
    amplifier_hz: f64,
) -> std::path::PathBuf {
    let shipped = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
    )
    .unwrap();
    let edited = shipped.replacen(
        "bandwidth_hz = 1000.0",
        &format!("bandwidth_hz = {amplifier_hz:?}"),
        1,
    );
    assert!(amplifier_hz == 1000.0 || edited != shipped);
    std::fs::write(dir.join("sr4dof-ch5.toml"), edited).unwrap();
    let file = dir.join("c.toml");
    std::fs::write(
        &file,
        format!("config = \"sr4dof-ch5.toml\"\nseed = {seed}\n[grid]\noperating_point_pct = {operating_points_pct}\nmass_asymmetry = [0.10]\n"),
    )
    .unwrap();
    file
}

/// A campaign's done cells (its bench's amplifier at 800 Hz, not the
/// built-in 1 kHz), overlaid from its directory: in order of operating
/// point, coloured by a sequential map, each fitted as `bench fit
/// cells/NNN/frf.csv --config DIR/bench.toml` (not as on the built-in
/// bench), each verdict the model's at its cell (the campaign's
/// `cells.csv`); the default figure in the directory, refused when it
/// exists; mixed with a recording, labelled.
#[test]
fn a_campaigns_cells_are_overlaid_in_order() {
    let dir = tmp();
    let d = dir.path();
    // Its amplifier is not the built-in bench's: the cells must be fitted
    // with the campaign's bench.
    let file = campaign_file(d, 62, "[8.0, 2.0, 5.0]", 800.0);
    let camp = d.join("camp");
    let camp_s = camp.to_str().unwrap();
    let o = run(&[
        "campaign",
        "run",
        file.to_str().unwrap(),
        "--out",
        camp_s,
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let cells_csv = std::fs::read_to_string(camp.join("cells.csv")).unwrap();
    let header: Vec<&str> = cells_csv.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let model_of: Vec<(usize, bool)> = cells_csv
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[col("index")].parse().unwrap(),
                f[col("model_cnmp")] == "true",
            )
        })
        .collect();
    let bench_toml = camp.join("bench.toml");
    let bench_toml = bench_toml.to_str().unwrap();

    let o = run(&["plot", "bode", camp_s, "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert_eq!(s["plot"], camp.join("bode-overlay.png").to_str().unwrap());
    assert!(camp.join("bode-overlay.png").is_file());
    assert_eq!(s["palette"], "sequential");
    assert!(
        s["colors_note"]
            .as_str()
            .unwrap()
            .contains("operating point"),
        "{}",
        s["colors_note"]
    );
    assert_eq!(s["model"]["config"], bench_toml);
    let traces = s["traces"].as_array().unwrap();
    assert_eq!(traces.len(), 3);
    let ops: Vec<f64> = traces
        .iter()
        .map(|t| t["operating_point_m"].as_f64().unwrap())
        .collect();
    assert!(ops.windows(2).all(|w| w[0] < w[1]), "ordered: {ops:?}");
    for t in traces {
        let cell = t["cell"].as_u64().unwrap() as usize;
        let csv = camp.join(format!("cells/{cell:03}/frf.csv"));
        assert_eq!(t["input"], csv.to_str().unwrap());
        assert_eq!(t["config"], bench_toml);
        let with_bench = fit(csv.to_str().unwrap(), Some(bench_toml));
        assert_as_fit(t, &with_bench);
        assert_eq!(t["amplifier_bandwidth_hz"], 800.0);
        // Not the fit on the built-in bench's path.
        let builtin = fit(csv.to_str().unwrap(), None);
        assert_eq!(builtin["amplifier_bandwidth_hz"], 1000.0);
        assert_ne!(builtin["fit"], with_bench["fit"], "cell {cell}");
        let model = model_of.iter().find(|(i, _)| *i == cell).unwrap().1;
        assert_eq!(
            t["verdict"]["cmp_cnmp"].as_bool(),
            Some(model),
            "cell {cell}"
        );
        assert!(t["label"]
            .as_str()
            .unwrap()
            .starts_with(&format!("cell {cell:03} (")));
    }
    // A second run refuses the figure it made, and replaces it when told.
    let o = run(&["plot", "bode", camp_s]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("bode-overlay.png") && stderr(&o).contains("--overwrite"));
    let o = run(&["plot", "bode", camp_s, "--overwrite"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));

    // Mixed with a recording, labelled: a few traces, a qualitative map.
    let rec = chirp(d, "ref", &["--mass-asymmetry", "-0.1"]);
    let out = path_in(d, "mixed.png");
    let o = run(&[
        "plot",
        "nyquist",
        camp_s,
        &rec,
        "--label",
        "Y1o sweep",
        "--label",
        "reference",
        "--out",
        &out,
        "--json",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert_eq!(s["palette"], "qualitative");
    let labels: Vec<&str> = s["traces"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["label"].as_str().unwrap())
        .collect();
    assert_eq!(labels.len(), 4);
    assert!(
        labels[..3].iter().all(|l| l.starts_with("Y1o sweep cell ")),
        "{labels:?}"
    );
    assert_eq!(labels[3], "reference");
}

/// The daemon's `plot` job gives the local run's summary (but the
/// figure's path, in its recordings directory) and refuses what the CLI
/// refuses.
#[test]
fn the_daemon_plots_as_the_cli_does() {
    let dm = Daemon::start();
    let sock = dm.sock();
    let d = dm.dir.path();
    let cfg = dm.config.to_str().unwrap();
    let a = chirp(d, "a", &["--config", cfg]);
    let b = chirp(d, "b", &["--config", cfg, "--operating-point-pct", "3"]);
    for kind in ["bode", "nyquist"] {
        let local = run(&[
            "plot",
            kind,
            &a,
            &b,
            "--out",
            &path_in(d, &format!("l-{kind}.png")),
            "--json",
        ]);
        assert!(local.status.success(), "{}", stderr(&local));
        let remote = run(&["plot", kind, &a, &b, "--daemon", &sock, "--json"]);
        assert!(remote.status.success(), "{}", stderr(&remote));
        let (mut l, mut r) = (json_stdout(&local), json_stdout(&remote));
        let figure = r["plot"].as_str().unwrap().to_string();
        assert!(Path::new(&figure).starts_with(d.join("rec")), "{figure}");
        assert!(figure.ends_with(&format!(".{kind}.png")), "{figure}");
        assert!(Path::new(&figure).is_file());
        l.as_object_mut().unwrap().remove("plot");
        r.as_object_mut().unwrap().remove("plot");
        assert_eq!(l, r);
    }
    // Refused as the CLI refuses: a missing input, a bad label count; a
    // relative path on the socket.
    let missing = path_in(d, "missing.csv");
    let o = run(&["plot", "bode", &a, &missing, "--daemon", &sock]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains(&missing), "{}", stderr(&o));
    let o = run(&[
        "plot", "bode", &a, "--label", "x", "--label", "y", "--daemon", &sock,
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("labels"), "{}", stderr(&o));
    let o = run(&["plot", "bode", &a, "--out", "x.png", "--daemon", &sock]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--out"), "{}", stderr(&o));
    let mut c = dm.client();
    let r = c.call("plot", json!({ "kind": "bode", "inputs": ["a.mcap"] }));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("params.inputs"),
        "{r}"
    );
    let r = c.call("plot", json!({ "kind": "polar", "inputs": [a] }));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
}

/// Bad input, generated from a good CSV (a field made NaN, inf or
/// negative, lines swapped, a line cut short, an extra field, the header
/// changed, the file empty, only the header, binary garbage, cut at random
/// bytes), and inputs that are not FRFs at all (a missing path, a text
/// file, a garbage `.mcap`, a recording without `/sysid/frf`, an empty
/// directory, a campaign without a done cell): each refused with exit 2
/// naming the input, nothing written. A file cut at a line boundary is
/// still an FRF and is plotted.
#[test]
fn bad_inputs_are_refused_naming_the_input_and_nothing_is_written() {
    let dir = tmp();
    let d = dir.path();
    let good_mcap = chirp(d, "good", &["--duration-s", "10"]);
    let good = path_in(d, "good.frf.csv");
    let text = std::fs::read_to_string(&good).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let (header, body) = (lines[0], &lines[1..]);
    let n = body.len();
    let mut cases: Vec<(String, Vec<u8>)> = Vec::new();
    let with = |rows: Vec<String>| format!("{header}\n{}\n", rows.join("\n")).into_bytes();
    let rows = || body.iter().map(|s| s.to_string()).collect::<Vec<String>>();
    for (col, bad) in [
        (0, "NaN"),
        (1, "NaN"),
        (2, "inf"),
        (3, "NaN"),
        (0, "-1"),
        (1, "0"),
        (3, "1.5"),
        (4, "-inf"),
        (2, "x"),
    ] {
        for i in [0, n / 3, n - 1] {
            let mut r = rows();
            let mut f: Vec<&str> = body[i].split(',').collect();
            f[col] = bad;
            r[i] = f.join(",");
            cases.push((format!("{bad} in column {col} at line {i}"), with(r)));
        }
    }
    for i in [1, n / 2, n - 1] {
        let mut r = rows();
        r.swap(i, i - 1);
        cases.push((format!("lines {i} and {} swapped", i - 1), with(r)));
        let mut r = rows();
        r[i] = r[i - 1].clone();
        cases.push((format!("line {i} repeated"), with(r)));
        let mut r = rows();
        let f: Vec<&str> = body[i].split(',').collect();
        r[i] = f[..3].join(",");
        cases.push((format!("line {i} cut short"), with(r)));
        let mut r = rows();
        r[i] = format!("{},1", body[i]);
        cases.push((format!("line {i} with an extra field"), with(r)));
    }
    cases.push((
        "the header changed".into(),
        text.replacen("coherence", "gamma", 1).into_bytes(),
    ));
    cases.push(("empty".into(), Vec::new()));
    cases.push(("only the header".into(), format!("{header}\n").into_bytes()));
    cases.push(("nine lines".into(), with(rows()[..9].to_vec())));
    let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = || {
        seed = bench::splitmix::splitmix64(seed);
        seed
    };
    for k in 0..3 {
        let garbage: Vec<u8> = (0..4096).map(|_| (next() >> 56) as u8).collect();
        cases.push((format!("binary garbage {k}"), garbage));
    }
    for (k, (what, bytes)) in cases.into_iter().enumerate() {
        let p = path_in(d, &format!("bad{k}.csv"));
        std::fs::write(&p, &bytes).unwrap();
        let before = listing(d);
        let o = run(&["plot", "bode", &good, &p, "--out", &path_in(d, "x.png")]);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{what}: {err}");
        assert!(
            err.contains(&p),
            "{what}: the message names the input: {err}"
        );
        assert_eq!(listing(d), before, "{what}: something was written");
        std::fs::remove_file(&p).unwrap();
    }
    // Cut at random bytes: exit 2 naming it, or, cut where it is still an
    // FRF, plotted; never anything else.
    for k in 0..12 {
        let at = 40 + (next() as usize) % (text.len() - 40);
        let p = path_in(d, &format!("cut{k}.csv"));
        std::fs::write(&p, &text.as_bytes()[..at]).unwrap();
        let out = path_in(d, &format!("cut{k}.png"));
        let o = run(&["plot", "nyquist", &p, "--out", &out]);
        match o.status.code() {
            // A shorter FRF (its fit may be flagged: 9).
            Some(0 | 9) => assert!(Path::new(&out).is_file()),
            Some(2) => {
                assert!(stderr(&o).contains(&p), "{}", stderr(&o));
                assert!(!Path::new(&out).exists());
            }
            other => panic!("cut at {at}: {other:?}: {}", stderr(&o)),
        }
    }

    // Not FRFs at all.
    let text_file = path_in(d, "notes.txt");
    std::fs::write(&text_file, "a lab note, not an FRF\n").unwrap();
    let garbage_mcap = path_in(d, "garbage.mcap");
    std::fs::write(&garbage_mcap, b"\x89MCAP0\r\nnot really").unwrap();
    let step = path_in(d, "step.mcap");
    let o = run(&["control", "--fast", "--out", &step]);
    assert!(o.status.success(), "{}", stderr(&o));
    let empty_dir = d.join("empty");
    std::fs::create_dir(&empty_dir).unwrap();
    let file = campaign_file(d, 1, "[4.0]", 1000.0);
    let undone = d.join("undone");
    let campaign = bench::campaign::file::Campaign::load(&file).unwrap();
    drop(bench::campaign::job::start(campaign, Some(&undone), 1).unwrap());
    for (what, p, expect) in [
        ("missing", path_in(d, "missing.csv"), "No such file"),
        ("a text file", text_file.clone(), "header"),
        ("a garbage recording", garbage_mcap.clone(), "MCAP"),
        ("a step recording", step.clone(), "/sysid/frf"),
        (
            "an empty directory",
            empty_dir.display().to_string(),
            "campaign",
        ),
        (
            "a campaign without a done cell",
            undone.display().to_string(),
            "no done cell",
        ),
    ] {
        for kind in ["bode", "nyquist"] {
            let before = listing(d);
            let o = run(&["plot", kind, &good_mcap, &p]);
            let err = stderr(&o);
            assert_eq!(o.status.code(), Some(2), "{what}: {err}");
            assert!(err.contains(&p) && err.contains(expect), "{what}: {err}");
            assert_eq!(listing(d), before, "{what}");
        }
    }

    // Options: labels one per input; an output in a missing directory; an
    // existing output without --overwrite; a config that is not one.
    let before = listing(d);
    for (args, flag) in [
        (vec!["--label", "only one"], "--label"),
        (vec!["--label", "a", "--label", ""], "--label"),
        (vec!["--out", "/nonexistent/dir/f.png"], "--out"),
        (vec!["--out", good.as_str()], "--out"),
        (vec!["--config", text_file.as_str()], "--config"),
        (vec!["--title", "a\u{7}bell"], "--title"),
    ] {
        let mut a = vec!["plot", "bode", good_mcap.as_str(), good.as_str()];
        a.extend(&args);
        let o = run(&a);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(flag), "{args:?}: {err}");
        assert_eq!(listing(d), before, "{args:?}");
    }
}
