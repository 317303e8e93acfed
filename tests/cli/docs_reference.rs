//! The book's generated reference pages: the exit statuses (from
//! `bench::error::EXIT_STATUSES`) and the recording channels (from the
//! recordings of a chirp and a step run: topic, encoding, schema and, for
//! each JSON channel, its fields with their schema descriptions). Each page
//! holds its generated part between the markers
//! `<!-- generated: … -->` and `<!-- end generated -->`; the test fails when
//! that part is not what the code gives now, and `BENCH_BLESS=1` rewrites
//! it (then review the diff).

use crate::common::{path_in, run, tmp};
use bench::error::EXIT_STATUSES;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;

const END: &str = "<!-- end generated -->";

/// Checks (or, with `BENCH_BLESS=1`, rewrites) the generated part of
/// `page` (from the repository root) against `body`.
fn check_generated(page: &str, source: &str, body: &str) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(page);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{page}: {e}"));
    let begin = format!("<!-- generated: {source}; BENCH_BLESS=1 tests/run --test cli docs_reference rewrites it -->");
    let a = text
        .find(&begin)
        .unwrap_or_else(|| panic!("{page} lacks the marker {begin}"));
    let b = text[a..]
        .find(END)
        .map(|i| a + i)
        .unwrap_or_else(|| panic!("{page} lacks {END} after its generated part"));
    let now = &text[a + begin.len()..b];
    let want = format!("\n{body}");
    if now == want {
        return;
    }
    if std::env::var_os("BENCH_BLESS").is_some_and(|v| v == "1") {
        let new = format!("{}{want}{}", &text[..a + begin.len()], &text[b..]);
        std::fs::write(&path, new).unwrap();
        return;
    }
    panic!(
        "{page} is stale: its generated part is not what {source} gives now.\n--- generated now ---\n{body}--- in the page ---{now}\nRun BENCH_BLESS=1 tests/run --test cli docs_reference and review the diff."
    );
}

/// The first paragraph of a schema node's description ("" without one).
fn first_paragraph(node: &Value) -> String {
    node.get("description")
        .and_then(Value::as_str)
        .unwrap_or("")
        .split("\n\n")
        .next()
        .unwrap_or("")
        .to_string()
}

/// A table cell: pipes escaped, one line.
fn cell(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', " ")
}

#[test]
fn the_exit_status_page_is_the_codes_table() {
    let mut body = String::from("| status | meaning | commands |\n|---|---|---|\n");
    for s in EXIT_STATUSES {
        let commands = if s.commands.is_empty() {
            "every command".to_string()
        } else {
            s.commands
                .iter()
                .map(|c| format!("`{c}`"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        body.push_str(&format!(
            "| {} | {} | {commands} |\n",
            s.code,
            cell(s.meaning)
        ));
    }
    check_generated(
        "docs/src/reference/exit-statuses.md",
        "bench::error::EXIT_STATUSES",
        &body,
    );
}

/// One recorded channel as the page lists it.
struct Channel {
    message_encoding: String,
    schema_name: String,
    schema_encoding: String,
    /// JSON channels: (field, type, description) of the top-level object.
    fields: Vec<(String, String, String)>,
    /// The jobs whose recording has it.
    jobs: Vec<&'static str>,
}

/// The JSON type of a schema node, as the page names it.
fn type_of(node: &Value, root: &Value) -> String {
    if let Some(r) = node.get("$ref").and_then(Value::as_str) {
        let name = r.rsplit('/').next().unwrap_or(r);
        let target = r
            .strip_prefix('#')
            .and_then(|p| root.pointer(p))
            .unwrap_or(&Value::Null);
        if target.get("enum").is_some() || target.get("oneOf").is_some() {
            return format!("{name} (enum)");
        }
        return name.to_string();
    }
    match node.get("type") {
        Some(Value::String(t)) if t == "array" => {
            let item = node.get("items").map(|i| type_of(i, root));
            format!("array of {}", item.unwrap_or_else(|| "values".into()))
        }
        Some(Value::String(t)) => t.clone(),
        Some(Value::Array(ts)) => ts
            .iter()
            .filter_map(Value::as_str)
            .collect::<Vec<_>>()
            .join(" or "),
        _ => {
            for k in ["anyOf", "oneOf"] {
                if let Some(alts) = node.get(k).and_then(Value::as_array) {
                    return alts
                        .iter()
                        .map(|a| type_of(a, root))
                        .collect::<Vec<_>>()
                        .join(" or ");
                }
            }
            "value".into()
        }
    }
}

fn add_channels(path: &Path, job: &'static str, out: &mut BTreeMap<String, Channel>) {
    let bytes = std::fs::read(path).expect("recording");
    let summary = mcap::Summary::read(&bytes)
        .expect("mcap summary")
        .expect("a summary section");
    for ch in summary.channels.values() {
        let entry = out.entry(ch.topic.clone()).or_insert_with(|| {
            let schema = ch.schema.as_ref().expect("every channel has a schema");
            let mut fields = Vec::new();
            if schema.encoding == "jsonschema" {
                let root: Value = serde_json::from_slice(&schema.data).expect("schema is JSON");
                if let Some(props) = root.get("properties").and_then(Value::as_object) {
                    for (name, node) in props {
                        fields.push((name.clone(), type_of(node, &root), first_paragraph(node)));
                    }
                }
            }
            Channel {
                message_encoding: ch.message_encoding.clone(),
                schema_name: schema.name.clone(),
                schema_encoding: schema.encoding.clone(),
                fields,
                jobs: Vec::new(),
            }
        });
        if !entry.jobs.contains(&job) {
            entry.jobs.push(job);
        }
    }
}

#[test]
fn the_recording_channels_page_is_the_recordings() {
    let dir = tmp();
    let chirp = path_in(dir.path(), "chirp.mcap");
    let control = path_in(dir.path(), "control.mcap");
    let track_dir = path_in(dir.path(), "track");
    let track = path_in(dir.path(), "track/trial-00-standstill.mcap");
    let runs: [(&'static str, &str, Vec<&str>); 3] = [
        (
            "chirp",
            &chirp,
            vec![
                "chirp",
                "--out",
                &chirp,
                "--duration-s",
                "1",
                "--f-start-hz",
                "20",
            ],
        ),
        (
            "control",
            &control,
            vec!["control", "--fast", "--out", &control, "--duration-s", "1"],
        ),
        (
            "track",
            &track,
            vec![
                "track",
                "--out",
                &track_dir,
                "--periods",
                "1",
                "--trials",
                "1",
            ],
        ),
    ];
    let mut chans = BTreeMap::new();
    for (job, recording, args) in &runs {
        let o = run(args);
        assert!(
            o.status.success(),
            "bench {args:?}: {:?}\n{}",
            o.status,
            String::from_utf8_lossy(&o.stderr)
        );
        add_channels(Path::new(recording), job, &mut chans);
    }
    assert!(chans.len() >= 5, "{} channels", chans.len());
    let mut body = String::from(
        "| topic | jobs | message encoding | schema (encoding) |\n|---|---|---|---|\n",
    );
    for (topic, c) in &chans {
        body.push_str(&format!(
            "| `{topic}` | {} | {} | `{}` ({}) |\n",
            c.jobs.join(", "),
            c.message_encoding,
            c.schema_name,
            c.schema_encoding
        ));
    }
    for (topic, c) in &chans {
        if c.fields.is_empty() {
            continue;
        }
        body.push_str(&format!(
            "\n## `{topic}`\n\n| field | type | meaning |\n|---|---|---|\n"
        ));
        for (name, ty, desc) in &c.fields {
            body.push_str(&format!("| `{name}` | {} | {} |\n", cell(ty), cell(desc)));
        }
    }
    check_generated(
        "docs/src/reference/channels.md",
        "the channels of a `bench chirp`, a `bench control --fast` and a `bench track` recording",
        &body,
    );
}

/// The JSON outputs page: for each command's `--json` summary (the type
/// `emit` prints, which must derive `JsonSchema`: the compiler holds every
/// summary to it), its fields, and every type they use, once, from the
/// types' schemas (their doc comments). Every field has a description.
#[test]
fn the_json_outputs_page_is_the_summaries_schemas() {
    use schemars::schema_for;
    macro_rules! outputs {
        ($($command:literal: $t:ty),* $(,)?) => {
            vec![$(($command, schema_for!($t).to_value())),*]
        };
    }
    let outputs: Vec<(&str, Value)> = outputs![
        "bench chirp": bench::jobs::chirp::ChirpSummary,
        "bench control": bench::jobs::control::ControlSummary,
        "bench fit": bench::jobs::fit::FitResult,
        "bench design": bench::jobs::design::DesignSummary,
        "bench track": bench::jobs::track::TrackSummary,
        "bench analyze": bench::jobs::analyze::AnalyzeSummary,
        "bench map": bench::jobs::map::MapResult,
        "bench plot": bench::jobs::plot::PlotSummary,
        "bench campaign": bench::campaign::run::CampaignSummary,
        "bench catalogue": bench::jobs::catalogue::CatalogueSummary,
        "bench upload": bench::upload::once::UploadSummary,
        "bench recover": bench::record::recover::Recovered,
    ];
    let mut missing = Vec::new();
    // A type's rows: its fields, or its variants.
    let mut describe = |name: &str, node: &Value, root: &Value| -> String {
        let mut out = String::new();
        if let Some(props) = node.get("properties").and_then(Value::as_object) {
            out.push_str("| field | type | meaning |\n|---|---|---|\n");
            for (field, sub) in props {
                let desc = first_paragraph(sub);
                if desc.is_empty() {
                    missing.push(format!("{name}.{field}"));
                }
                out.push_str(&format!(
                    "| `{field}` | {} | {} |\n",
                    cell(&type_of(sub, root)),
                    cell(&desc)
                ));
            }
        } else if let Some(values) = node.get("enum").and_then(Value::as_array) {
            let v: Vec<String> = values.iter().map(|v| format!("`{v}`")).collect();
            out.push_str(&format!("One of {}.\n", v.join(", ")));
        } else if let Some(alts) = node
            .get("oneOf")
            .or_else(|| node.get("anyOf"))
            .and_then(Value::as_array)
        {
            out.push_str("| one of | meaning |\n|---|---|\n");
            for a in alts {
                let what = match (a.get("const"), a.get("enum")) {
                    (Some(c), _) => format!("`{c}`"),
                    (_, Some(Value::Array(e))) => e
                        .iter()
                        .map(|v| format!("`{v}`"))
                        .collect::<Vec<_>>()
                        .join(", "),
                    _ => type_of(a, root),
                };
                out.push_str(&format!(
                    "| {} | {} |\n",
                    cell(&what),
                    cell(&first_paragraph(a))
                ));
            }
        } else {
            out.push_str(&format!("{}.\n", type_of(node, root)));
        }
        out
    };
    let mut body = String::new();
    // Each type once: (name, its schema) as first met.
    let mut types: BTreeMap<String, Value> = BTreeMap::new();
    for (command, root) in &outputs {
        let title = root.get("title").and_then(Value::as_str).unwrap_or("?");
        body.push_str(&format!(
            "\n## `{command} --json`: `{title}`\n\n{}\n\n",
            first_paragraph(root)
        ));
        body.push_str(&describe(title, root, root));
        if let Some(defs) = root.get("$defs").and_then(Value::as_object) {
            for (name, def) in defs {
                match types.get(name) {
                    None => {
                        types.insert(name.clone(), def.clone());
                    }
                    Some(seen) => assert_eq!(
                        seen, def,
                        "two types named {name} with different schemas: the page would confuse them"
                    ),
                }
            }
        }
    }
    body.push_str("\n# Types\n\nThe types the summaries name, in alphabetical order.\n");
    let roots: Value = Value::Object(
        [(
            "$defs".to_string(),
            Value::Object(types.clone().into_iter().collect()),
        )]
        .into_iter()
        .collect(),
    );
    for (name, def) in &types {
        body.push_str(&format!("\n## `{name}`\n\n"));
        let d = first_paragraph(def);
        if !d.is_empty() {
            body.push_str(&format!("{d}\n\n"));
        }
        body.push_str(&describe(name, def, &roots));
    }
    assert!(
        missing.is_empty(),
        "fields without a description (a doc comment on the field): {missing:?}"
    );
    check_generated(
        "docs/src/reference/json.md",
        "the `JsonSchema` of each command's `--json` summary",
        &body,
    );
}
