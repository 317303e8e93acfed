//! The shipped Foxglove/Lichtblick layout (`foxglove/bench-layout.json`,
//! issue 30 part 4) fits what `bench` records and serves.
//!
//! The layout is the JSON a layout import reads (Lichtblick's `LayoutData`,
//! `packages/suite-base/src/context/CurrentLayoutContext/actions.ts`, as in
//! Foxglove Studio it forked): `configById` (one config per panel, keyed
//! `Type!id`), the mosaic tree `layout`, `globalVariables`, `userNodes`,
//! `playbackConfig`. This test checks
//!
//! - the mosaic tree names exactly the panels of `configById`, each once,
//!   and every split has a direction and a percentage;
//! - each panel's type is one the layout uses and its config has only keys
//!   that type's config has (the types of Lichtblick's `panels/Plot/utils/
//!   config.ts`, `panels/StateTransitions/types.ts`, `panels/Log/types.ts`,
//!   `panels/RawMessages/types.ts`, `panels/Indicator/types.ts`), so a
//!   misspelt key that a panel would silently ignore fails here;
//! - every message path (`/topic.field[:].@modifier`) names a channel that a
//!   real run records (and so the live view serves: it serves every channel
//!   of the recording) and fields that channel's schema has, read from the
//!   recordings of a short `bench chirp` and a short `bench control` run:
//!   the JSON Schemas of the JSON channels, the `FileDescriptorSet` of the
//!   protobuf ones. A renamed field breaks this test. The path's shape
//!   suits its panel: a number for a Plot (one per message against time,
//!   an array sliced with `[:]` against a custom x axis from the same
//!   message), a number or string for State Transitions and the Indicator,
//!   a `foxglove.Log` channel for the Log panel;
//! - every channel a panel shows carried messages in those runs;
//! - the README's table of the layout (*Live view*, *The layout*) has one
//!   row per panel, by its title, naming what the panel shows.
//!
//! The checker is shown to catch mistakes: the tests at the end break the
//! layout one way each (a renamed field, an unknown topic, an unsliced
//! array, a slice on a number, a misspelt key, a panel left out of the
//! mosaic) and expect the one matching error.

use crate::common;

use common::*;
use serde_json::{json, Value};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::sync::OnceLock;

/// What a message path can reach in a channel's message.
#[derive(Debug, Clone, PartialEq)]
enum Shape {
    /// A number: JSON `number`/`integer`/`boolean`, protobuf scalars, and
    /// protobuf enums (Foxglove and Lichtblick decode them as numbers).
    Number,
    /// A string: JSON `string`, or an enumeration of strings.
    Text,
    /// An array of the inner shape.
    Array(Box<Shape>),
    /// An object (message) with named fields.
    Object(BTreeMap<String, Shape>),
    /// Anything: the schema does not say (e.g. a field of free-form
    /// JSON); no path into it can be checked.
    Any,
}

/// One recorded channel.
#[derive(Debug, Clone)]
struct Chan {
    schema_name: String,
    shape: Shape,
    /// Messages it carried in the runs.
    messages: u64,
}

type Channels = BTreeMap<String, Chan>;

/// The shape of a JSON Schema node; `$ref`s resolve in `root`'s `$defs`.
fn json_shape(node: &Value, root: &Value, depth: usize) -> Result<Shape, String> {
    if depth > 32 {
        return Err("schema nests too deep".into());
    }
    if let Some(r) = node.get("$ref").and_then(Value::as_str) {
        let name = r
            .strip_prefix("#/$defs/")
            .ok_or_else(|| format!("unsupported $ref {r}"))?;
        let def = root["$defs"]
            .get(name)
            .ok_or_else(|| format!("no $defs/{name}"))?;
        return json_shape(def, root, depth + 1);
    }
    for key in ["anyOf", "oneOf", "allOf"] {
        if let Some(branches) = node.get(key).and_then(Value::as_array) {
            let mut shapes = Vec::new();
            for b in branches {
                if b.get("type") == Some(&json!("null")) {
                    continue;
                }
                shapes.push(json_shape(b, root, depth + 1)?);
            }
            shapes.dedup();
            return match shapes.as_slice() {
                [one] => Ok(one.clone()),
                _ => Err(format!("{key} of different shapes {shapes:?}")),
            };
        }
    }
    let types: Vec<&str> = match node.get("type") {
        Some(Value::String(t)) => vec![t.as_str()],
        Some(Value::Array(ts)) => ts.iter().filter_map(Value::as_str).collect(),
        _ => vec![],
    };
    let types: Vec<&str> = types.into_iter().filter(|t| *t != "null").collect();
    if let Some(props) = node.get("properties").and_then(Value::as_object) {
        let mut fields = BTreeMap::new();
        for (name, p) in props {
            fields.insert(name.clone(), json_shape(p, root, depth + 1)?);
        }
        return Ok(Shape::Object(fields));
    }
    match types.as_slice() {
        ["array"] => {
            let items = if let Some(items) = node.get("items") {
                json_shape(items, root, depth + 1)?
            } else {
                // A tuple (`prefixItems`): one shape if all its members
                // have it.
                let mut shapes = Vec::new();
                for p in node["prefixItems"].as_array().into_iter().flatten() {
                    shapes.push(json_shape(p, root, depth + 1)?);
                }
                shapes.dedup();
                match shapes.as_slice() {
                    [one] => one.clone(),
                    _ => Shape::Any,
                }
            };
            Ok(Shape::Array(Box::new(items)))
        }
        ["object"] => Ok(Shape::Object(BTreeMap::new())),
        ["number" | "integer" | "boolean"] => Ok(Shape::Number),
        ["string"] => Ok(Shape::Text),
        [] if node.get("const").is_some_and(Value::is_string) => Ok(Shape::Text),
        [] if node.get("enum").is_some() => Ok(Shape::Text),
        [] => Ok(Shape::Any),
        other => Err(format!("unsupported type {other:?}")),
    }
}

/// The shape of a protobuf message, from its descriptor.
fn proto_shape(m: &prost_reflect::MessageDescriptor, depth: usize) -> Shape {
    use prost_reflect::Kind;
    let mut fields = BTreeMap::new();
    for f in m.fields() {
        let base = match f.kind() {
            Kind::Message(inner) if depth < 32 => proto_shape(&inner, depth + 1),
            Kind::Message(_) => Shape::Object(BTreeMap::new()),
            Kind::String | Kind::Bytes => Shape::Text,
            _ => Shape::Number,
        };
        let shape = if f.is_list() {
            Shape::Array(Box::new(base))
        } else {
            base
        };
        fields.insert(f.name().to_string(), shape);
    }
    Shape::Object(fields)
}

/// Adds the channels of the recording at `path` (its summary section) to
/// `out`, with their shapes and message counts.
fn add_channels(path: &Path, out: &mut Channels) {
    let bytes = std::fs::read(path).expect("recording");
    let summary = mcap::Summary::read(&bytes)
        .expect("mcap summary")
        .expect("a complete recording has a summary");
    let counts = summary
        .stats
        .as_ref()
        .map(|s| s.channel_message_counts.clone())
        .unwrap_or_default();
    for (id, ch) in &summary.channels {
        let schema = ch.schema.as_ref().expect("channel has a schema");
        let shape = match schema.encoding.as_str() {
            "jsonschema" => {
                let v: Value = serde_json::from_slice(&schema.data).expect("schema is JSON");
                json_shape(&v, &v, 0).unwrap_or_else(|e| panic!("{}: {e}", ch.topic))
            }
            "protobuf" => {
                let pool = prost_reflect::DescriptorPool::decode(schema.data.as_ref())
                    .expect("FileDescriptorSet");
                let m = pool
                    .get_message_by_name(&schema.name)
                    .expect("message in its schema");
                proto_shape(&m, 0)
            }
            other => panic!("{}: schema encoding {other}", ch.topic),
        };
        let n = counts.get(id).copied().unwrap_or(0);
        let entry = out.entry(ch.topic.clone()).or_insert(Chan {
            schema_name: schema.name.clone(),
            shape: shape.clone(),
            messages: 0,
        });
        assert_eq!(
            (&entry.schema_name, &entry.shape),
            (&schema.name, &shape),
            "{}: the same channel differs between the runs",
            ch.topic
        );
        entry.messages += n;
    }
}

/// The channels of a short chirp and a short step run (once per test
/// binary): every topic the layout may show.
fn channels() -> &'static Channels {
    static CHANNELS: OnceLock<Channels> = OnceLock::new();
    CHANNELS.get_or_init(|| {
        let dir = tmp();
        let chirp = path_in(dir.path(), "chirp.mcap");
        let control = path_in(dir.path(), "control.mcap");
        for args in [
            vec![
                "chirp",
                "--out",
                &chirp,
                "--duration-s",
                "1",
                "--f-start-hz",
                "20",
            ],
            vec!["control", "--fast", "--out", &control, "--duration-s", "1"],
        ] {
            let o = run(&args);
            assert!(
                o.status.success(),
                "bench {args:?}: {:?}\n{}",
                o.status,
                String::from_utf8_lossy(&o.stderr)
            );
        }
        let mut out = Channels::new();
        add_channels(Path::new(&chirp), &mut out);
        add_channels(Path::new(&control), &mut out);
        out
    })
}

/// The shipped layout.
fn layout() -> Value {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("foxglove/bench-layout.json");
    serde_json::from_str(&std::fs::read_to_string(&p).expect("foxglove/bench-layout.json"))
        .expect("the layout is JSON")
}

/// The Plot panel's math modifiers (`.@name` at the end of a path):
/// Lichtblick's `panels/Plot/constants.ts` `MATH_FUNCTIONS` and
/// `utils/mathFunctions.ts`; `derivative` only against time.
const MODIFIERS: &[&str] = &[
    "abs",
    "acos",
    "asin",
    "atan",
    "ceil",
    "cos",
    "log",
    "log1p",
    "log2",
    "log10",
    "round",
    "sign",
    "sin",
    "sqrt",
    "tan",
    "trunc",
    "negative",
    "deg2rad",
    "rad2deg",
    "derivative",
];

/// A message path resolved against its channel.
#[derive(Debug)]
struct Resolved {
    topic: String,
    /// The shape the path ends on (an array's elements once sliced).
    leaf: Shape,
    /// A slice with a range (`[:]`, `[a:b]`): the path gives many values.
    many: bool,
    modifier: Option<String>,
}

/// Resolves `path` (`/topic.field[slice].field….@modifier`, Foxglove's
/// message-path syntax, `packages/message-path/src/grammar.ne`; filters
/// `{…}` and quoted names are not used here and refused) against the
/// recorded channels.
fn resolve(path: &str, chans: &Channels) -> Result<Resolved, String> {
    if !path.starts_with('/') {
        return Err(format!(
            "`{path}`: a message path starts with its topic, /…"
        ));
    }
    let (topic, rest) = path.split_once('.').unwrap_or((path, ""));
    let chan = chans.get(topic).ok_or_else(|| {
        format!(
            "`{path}`: no channel {topic} in the recordings (channels: {})",
            chans.keys().cloned().collect::<Vec<_>>().join(", ")
        )
    })?;
    let mut shape = chan.shape.clone();
    let mut many = false;
    let mut modifier = None;
    let mut where_ = chan.schema_name.clone();
    let elements: Vec<&str> = if rest.is_empty() {
        vec![]
    } else {
        rest.split('.').collect()
    };
    for (i, el) in elements.iter().enumerate() {
        if let Some(m) = el.strip_prefix('@') {
            if i + 1 != elements.len() {
                return Err(format!("`{path}`: the modifier @{m} must come last"));
            }
            if !MODIFIERS.contains(&m) {
                return Err(format!("`{path}`: unknown modifier @{m}"));
            }
            modifier = Some(m.to_string());
            break;
        }
        let (name, slice) = match el.split_once('[') {
            Some((n, s)) => {
                let s = s
                    .strip_suffix(']')
                    .ok_or_else(|| format!("`{path}`: `{el}`: unclosed ["))?;
                (n, Some(s))
            }
            None => (*el, None),
        };
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(format!("`{path}`: `{el}` is not a field name"));
        }
        let fields = match &shape {
            Shape::Object(f) => f,
            Shape::Array(_) => {
                return Err(format!(
                    "`{path}`: {where_} is an array: slice it ([:] or [i]) before .{name}"
                ))
            }
            Shape::Any => {
                return Err(format!(
                "`{path}`: the schema does not say what {where_} holds: .{name} cannot be checked"
            ))
            }
            _ => return Err(format!("`{path}`: {where_} has no fields (.{name})")),
        };
        shape = fields.get(name).cloned().ok_or_else(|| {
            format!(
                "`{path}`: no field `{name}` in {where_} (fields: {})",
                fields.keys().cloned().collect::<Vec<_>>().join(", ")
            )
        })?;
        where_ = format!("{where_}.{name}");
        if let Some(s) = slice {
            let Shape::Array(inner) = shape else {
                return Err(format!("`{path}`: {where_} is not an array: no [{s}]"));
            };
            let ok = match s.split_once(':') {
                Some((a, b)) => {
                    many = true;
                    [a, b]
                        .iter()
                        .all(|x| x.is_empty() || x.parse::<i64>().is_ok())
                }
                None => s.parse::<i64>().is_ok(),
            };
            if !ok {
                return Err(format!("`{path}`: [{s}] is not a slice"));
            }
            shape = *inner;
        }
    }
    Ok(Resolved {
        topic: topic.to_string(),
        leaf: shape,
        many,
        modifier,
    })
}

/// The config keys each panel type has (Lichtblick's config types; see
/// the module docs), `foxglovePanelTitle` (`util/layout.ts`
/// `PANEL_TITLE_CONFIG_KEY`) on every panel.
fn allowed_keys(panel_type: &str) -> Option<&'static [&'static str]> {
    Some(match panel_type {
        "Plot" => &[
            "paths",
            "minXValue",
            "maxXValue",
            "minYValue",
            "maxYValue",
            "showLegend",
            "legendDisplay",
            "showPlotValuesInLegend",
            "showXAxisLabels",
            "showYAxisLabels",
            "isSynced",
            "xAxisVal",
            "xAxisPath",
            "followingViewWidth",
            "sidebarDimension",
            "foxglovePanelTitle",
        ],
        "StateTransitions" => &[
            "isSynced",
            "paths",
            "xAxisMaxValue",
            "xAxisMinValue",
            "xAxisRange",
            "showPoints",
            "foxglovePanelTitle",
        ],
        // The Log panel; `RosOut` is its type name in layouts.
        "RosOut" => &[
            "searchTerms",
            "minLogLevel",
            "topicToRender",
            "nameFilter",
            "foxglovePanelTitle",
        ],
        "RawMessages" => &[
            "diffEnabled",
            "diffMethod",
            "diffTopicPath",
            "expansion",
            "showFullMessageForDiff",
            "topicPath",
            "fontSize",
            "foxglovePanelTitle",
        ],
        "Indicator" => &[
            "fallbackColor",
            "fallbackLabel",
            "path",
            "rules",
            "style",
            "foxglovePanelTitle",
        ],
        _ => return None,
    })
}

/// Keys of a Plot series (`PlotPath`) and of a State Transitions series.
const PLOT_PATH_KEYS: &[&str] = &[
    "value",
    "enabled",
    "color",
    "label",
    "timestampMethod",
    "showLine",
    "lineSize",
];
const STATE_PATH_KEYS: &[&str] = &["value", "enabled", "color", "label", "timestampMethod"];

/// Errors of an object's keys: unknown ones, and missing required ones.
fn check_keys(what: &str, v: &Value, allowed: &[&str], required: &[&str], errs: &mut Vec<String>) {
    let Some(o) = v.as_object() else {
        errs.push(format!("{what}: not an object"));
        return;
    };
    for k in o.keys() {
        if !allowed.contains(&k.as_str()) {
            errs.push(format!("{what}: unknown key `{k}`"));
        }
    }
    for k in required {
        if !o.contains_key(*k) {
            errs.push(format!("{what}: missing key `{k}`"));
        }
    }
}

/// The panel ids the mosaic tree names, in order; errors of its splits.
fn mosaic_leaves(node: &Value, out: &mut Vec<String>, errs: &mut Vec<String>) {
    match node {
        Value::String(id) => out.push(id.clone()),
        Value::Object(o) => {
            check_keys(
                "layout split",
                node,
                &["direction", "first", "second", "splitPercentage"],
                &["direction", "first", "second"],
                errs,
            );
            if !matches!(
                o.get("direction").and_then(Value::as_str),
                Some("row" | "column")
            ) {
                errs.push(format!("layout split: direction {:?}", o.get("direction")));
            }
            if let Some(p) = o.get("splitPercentage") {
                if !p.as_f64().is_some_and(|p| p > 0.0 && p < 100.0) {
                    errs.push(format!("layout split: splitPercentage {p}"));
                }
            }
            for k in ["first", "second"] {
                if let Some(child) = o.get(k) {
                    mosaic_leaves(child, out, errs);
                }
            }
        }
        other => errs.push(format!("layout: a node is {other}")),
    }
}

/// A series' value: a Plot or State Transitions path.
fn check_series(
    what: &str,
    s: &Value,
    keys: &[&str],
    chans: &Channels,
    errs: &mut Vec<String>,
) -> Option<Resolved> {
    check_keys(
        what,
        s,
        keys,
        &["value", "enabled", "timestampMethod"],
        errs,
    );
    if !matches!(
        s["timestampMethod"].as_str(),
        Some("receiveTime" | "headerStamp")
    ) {
        errs.push(format!("{what}: timestampMethod {}", s["timestampMethod"]));
    }
    if !s["enabled"].is_boolean() {
        errs.push(format!("{what}: enabled {}", s["enabled"]));
    }
    let Some(path) = s["value"].as_str() else {
        errs.push(format!("{what}: value is not a string"));
        return None;
    };
    match resolve(path, chans) {
        Ok(r) => Some(r),
        Err(e) => {
            errs.push(format!("{what}: {e}"));
            None
        }
    }
}

/// Checks one panel's config; returns the topics it shows.
fn check_panel(
    id: &str,
    cfg: &Value,
    chans: &Channels,
    errs: &mut Vec<String>,
) -> BTreeSet<String> {
    let mut topics = BTreeSet::new();
    let Some((ty, _)) = id.split_once('!') else {
        errs.push(format!("{id}: a panel id is Type!name"));
        return topics;
    };
    let Some(allowed) = allowed_keys(ty) else {
        errs.push(format!("{id}: panel type {ty} is not one this test knows"));
        return topics;
    };
    match ty {
        "Plot" => {
            check_keys(id, cfg, allowed, &["paths", "xAxisVal"], errs);
            let x_mode = cfg["xAxisVal"].as_str().unwrap_or("");
            let custom = matches!(x_mode, "custom" | "currentCustom");
            if !matches!(x_mode, "timestamp" | "index" | "custom" | "currentCustom") {
                errs.push(format!("{id}: xAxisVal {}", cfg["xAxisVal"]));
            }
            let mut x_topic = None;
            if custom {
                let x = &cfg["xAxisPath"];
                check_keys(
                    &format!("{id} xAxisPath"),
                    x,
                    &["value", "enabled"],
                    &["value", "enabled"],
                    errs,
                );
                match x["value"].as_str().map(|p| resolve(p, chans)) {
                    Some(Ok(r)) => {
                        if r.leaf != Shape::Number || !r.many {
                            errs.push(format!(
                                "{id} xAxisPath: `{}` must give an array of numbers ([:])",
                                x["value"].as_str().unwrap_or("")
                            ));
                        }
                        x_topic = Some(r.topic.clone());
                        topics.insert(r.topic);
                    }
                    Some(Err(e)) => errs.push(format!("{id} xAxisPath: {e}")),
                    None => errs.push(format!("{id}: xAxisVal {x_mode} needs xAxisPath")),
                }
            }
            let paths = cfg["paths"].as_array().cloned().unwrap_or_default();
            if paths.is_empty() {
                errs.push(format!("{id}: no series"));
            }
            for (i, s) in paths.iter().enumerate() {
                let what = format!("{id} series {i}");
                let Some(r) = check_series(&what, s, PLOT_PATH_KEYS, chans, errs) else {
                    continue;
                };
                let path = s["value"].as_str().unwrap_or("");
                if let Shape::Array(_) = r.leaf {
                    errs.push(format!(
                        "{what}: `{path}` is an array: slice it ([:] for all, [i] for one)"
                    ));
                } else if r.leaf != Shape::Number {
                    errs.push(format!("{what}: `{path}` is not a number ({:?})", r.leaf));
                } else if x_mode == "timestamp" && r.many {
                    errs.push(format!(
                        "{what}: `{path}` gives many values per message: not against time"
                    ));
                } else if x_mode != "timestamp" && !r.many {
                    errs.push(format!(
                        "{what}: `{path}` gives one value per message: slice an array ([:]) for xAxisVal {x_mode}"
                    ));
                }
                if x_mode != "timestamp" && r.modifier.as_deref() == Some("derivative") {
                    errs.push(format!("{what}: @derivative only against time"));
                }
                if let Some(xt) = &x_topic {
                    if *xt != r.topic {
                        errs.push(format!(
                            "{what}: `{path}` is paired by index with the x axis of {xt}: use the same topic"
                        ));
                    }
                }
                topics.insert(r.topic);
            }
        }
        "StateTransitions" => {
            check_keys(id, cfg, allowed, &["paths", "isSynced"], errs);
            let paths = cfg["paths"].as_array().cloned().unwrap_or_default();
            if paths.is_empty() {
                errs.push(format!("{id}: no series"));
            }
            for (i, s) in paths.iter().enumerate() {
                let what = format!("{id} series {i}");
                let Some(r) = check_series(&what, s, STATE_PATH_KEYS, chans, errs) else {
                    continue;
                };
                if !matches!(r.leaf, Shape::Number | Shape::Text) || r.many || r.modifier.is_some()
                {
                    errs.push(format!(
                        "{what}: `{}` must give one number or string per message",
                        s["value"].as_str().unwrap_or("")
                    ));
                }
                topics.insert(r.topic);
            }
        }
        "RosOut" => {
            check_keys(id, cfg, allowed, &["topicToRender"], errs);
            let topic = cfg["topicToRender"].as_str().unwrap_or("");
            match chans.get(topic) {
                Some(c) if c.schema_name == "foxglove.Log" => {
                    topics.insert(topic.to_string());
                }
                Some(c) => errs.push(format!(
                    "{id}: {topic} is {}, not foxglove.Log",
                    c.schema_name
                )),
                None => errs.push(format!("{id}: no channel {topic:?} in the recordings")),
            }
        }
        "RawMessages" => {
            check_keys(id, cfg, allowed, &["topicPath"], errs);
            match cfg["topicPath"].as_str().map(|p| resolve(p, chans)) {
                Some(Ok(r)) if r.modifier.is_none() => {
                    topics.insert(r.topic);
                }
                Some(Ok(_)) => errs.push(format!("{id}: a modifier in topicPath")),
                Some(Err(e)) => errs.push(format!("{id}: {e}")),
                None => errs.push(format!("{id}: topicPath is not a string")),
            }
        }
        "Indicator" => {
            check_keys(id, cfg, allowed, &["path", "rules", "style"], errs);
            if !matches!(cfg["style"].as_str(), Some("bulb" | "background")) {
                errs.push(format!("{id}: style {}", cfg["style"]));
            }
            let leaf = match cfg["path"].as_str().map(|p| resolve(p, chans)) {
                Some(Ok(r)) if !r.many && r.modifier.is_none() => {
                    topics.insert(r.topic);
                    Some(r.leaf)
                }
                Some(Ok(_)) => {
                    errs.push(format!("{id}: the path must give one value per message"));
                    None
                }
                Some(Err(e)) => {
                    errs.push(format!("{id}: {e}"));
                    None
                }
                None => {
                    errs.push(format!("{id}: path is not a string"));
                    None
                }
            };
            for (i, rule) in cfg["rules"]
                .as_array()
                .cloned()
                .unwrap_or_default()
                .iter()
                .enumerate()
            {
                let what = format!("{id} rule {i}");
                let keys = ["color", "label", "operator", "rawValue"];
                check_keys(&what, rule, &keys, &keys, errs);
                if !matches!(
                    rule["operator"].as_str(),
                    Some("=" | "<" | "<=" | ">" | ">=")
                ) {
                    errs.push(format!("{what}: operator {}", rule["operator"]));
                }
                // A number is compared with the rule's value parsed as JSON
                // (`getMatchingRule.ts`).
                let raw = rule["rawValue"].as_str().unwrap_or("");
                if leaf == Some(Shape::Number)
                    && !serde_json::from_str::<Value>(raw)
                        .is_ok_and(|v| v.is_number() || v.is_boolean())
                {
                    errs.push(format!("{what}: rawValue {raw:?} is not a number"));
                }
            }
        }
        _ => unreachable!("allowed_keys knows {ty}"),
    }
    topics
}

/// Every error of `layout` against `chans`, and the topics its panels show.
fn check_layout(layout: &Value, chans: &Channels) -> (Vec<String>, BTreeSet<String>) {
    let mut errs = Vec::new();
    check_keys(
        "layout file",
        layout,
        &[
            "configById",
            "layout",
            "globalVariables",
            "userNodes",
            "playbackConfig",
            "version",
        ],
        &[
            "configById",
            "layout",
            "globalVariables",
            "userNodes",
            "playbackConfig",
        ],
        &mut errs,
    );
    if !layout["playbackConfig"]["speed"]
        .as_f64()
        .is_some_and(|s| s > 0.0)
    {
        errs.push(format!(
            "playbackConfig.speed {}",
            layout["playbackConfig"]["speed"]
        ));
    }
    let configs = layout["configById"]
        .as_object()
        .cloned()
        .unwrap_or_default();
    let mut leaves = Vec::new();
    mosaic_leaves(&layout["layout"], &mut leaves, &mut errs);
    let mut seen = BTreeSet::new();
    for id in &leaves {
        if !seen.insert(id.clone()) {
            errs.push(format!("layout: {id} appears twice"));
        }
        if !configs.contains_key(id) {
            errs.push(format!("layout: {id} has no config in configById"));
        }
    }
    for id in configs.keys() {
        if !seen.contains(id) {
            errs.push(format!("configById: {id} is not in the layout tree"));
        }
    }
    let mut topics = BTreeSet::new();
    for (id, cfg) in &configs {
        topics.extend(check_panel(id, cfg, chans, &mut errs));
    }
    (errs, topics)
}

#[test]
fn the_shipped_layout_fits_the_recorded_channels() {
    let chans = channels();
    let layout = layout();
    let (errs, topics) = check_layout(&layout, chans);
    assert!(
        errs.is_empty(),
        "foxglove/bench-layout.json:\n{}",
        errs.join("\n")
    );
    // What the issue asks the layout to show.
    for t in [
        "/bench/envelope",
        "/bench/sample",
        "/bench/event",
        "/bench/log",
        "/sysid/frf",
        "/sysid/summary",
        "/control/metrics",
    ] {
        assert!(topics.contains(t), "no panel shows {t}");
    }
    for t in &topics {
        assert!(chans[t].messages > 0, "{t}: no message in the runs");
    }
}

/// The layout with the string `from` replaced by `to` once (it must be
/// there), checked; its errors.
fn errors_with(from: &str, to: &str) -> Vec<String> {
    let text = serde_json::to_string(&layout()).unwrap();
    assert!(text.contains(from), "{from} is not in the layout");
    let broken: Value = serde_json::from_str(&text.replacen(from, to, 1)).unwrap();
    check_layout(&broken, channels()).0
}

/// Exactly one error, and it contains every one of `words`.
fn one_error_saying(errs: &[String], words: &[&str]) {
    assert_eq!(errs.len(), 1, "{errs:#?}");
    for w in words {
        assert!(errs[0].contains(w), "{:?} does not say {w:?}", errs[0]);
    }
}

#[test]
fn a_renamed_field_is_reported() {
    let errs = errors_with(
        "\"/bench/envelope.position_max_m\"",
        "\"/bench/envelope.position_maximum_m\"",
    );
    one_error_saying(
        &errs,
        &[
            "Plot!position",
            "no field `position_maximum_m`",
            "bench.Envelope",
        ],
    );
    let errs = errors_with(
        "\"/sysid/frf.coherence[:]\"",
        "\"/sysid/frf.coherence_sq[:]\"",
    );
    one_error_saying(&errs, &["no field `coherence_sq`", "bench.Frf"]);
}

#[test]
fn an_unknown_topic_is_reported() {
    let errs = errors_with("\"/bench/log\"", "\"/rosout\"");
    one_error_saying(&errs, &["RosOut!log", "/rosout"]);
    let errs = errors_with("\"/control/metrics\"", "\"/control/step_metrics\"");
    one_error_saying(&errs, &["no channel /control/step_metrics"]);
}

#[test]
fn a_path_of_the_wrong_shape_is_reported() {
    // An array against a custom x axis must be sliced.
    let errs = errors_with("\"/sysid/frf.phase_deg[:]\"", "\"/sysid/frf.phase_deg\"");
    one_error_saying(&errs, &["Plot!frf_phase", "phase_deg", "slice"]);
    // A number has no slice.
    let errs = errors_with(
        "\"/bench/envelope.setpoint_m\"",
        "\"/bench/envelope.setpoint_m[:]\"",
    );
    one_error_saying(&errs, &["setpoint_m is not an array"]);
    // A string does not plot.
    let errs = errors_with("\"/bench/envelope.setpoint_m\"", "\"/bench/event.kind\"");
    one_error_saying(&errs, &["/bench/event.kind", "not a number"]);
}

#[test]
fn a_misspelt_key_and_a_lost_panel_are_reported() {
    let errs = errors_with("\"xAxisVal\":\"timestamp\"", "\"xAxisValue\":\"timestamp\"");
    assert!(
        errs.iter().any(|e| e.contains("unknown key `xAxisValue`"))
            && errs.iter().any(|e| e.contains("missing key `xAxisVal`")),
        "{errs:#?}"
    );
    let errs = errors_with(
        "\"first\":\"RawMessages!chirp_summary\"",
        "\"first\":\"RawMessages!step_metrics\"",
    );
    assert!(
        errs.iter()
            .any(|e| e.contains("RawMessages!step_metrics appears twice"))
            && errs
                .iter()
                .any(|e| e.contains("RawMessages!chirp_summary is not in the layout tree")),
        "{errs:#?}"
    );
}

/// The message paths a panel shows (its series, its topic), not its x
/// axis.
fn shown_paths(cfg: &Value) -> Vec<String> {
    let mut out: Vec<String> = cfg["paths"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|s| s["value"].as_str().map(str::to_string))
        .collect();
    for k in ["topicPath", "topicToRender", "path"] {
        if let Some(p) = cfg[k].as_str() {
            out.push(p.to_string());
        }
    }
    out
}

/// The README's table of the layout (*Live view*, *The layout*) has one
/// row per panel, by its title, and the row names what the panel shows:
/// each of its paths from the first `.` on (the topic alone for a path
/// without fields).
#[test]
fn the_readme_describes_every_panel() {
    let readme = crate::common::docs_text();
    let start = readme
        .find("## The layout: `foxglove/bench-layout.json`")
        .expect("the book: Live view, The layout");
    let section = &readme[start..];
    let end = ["\n# ", "\n## ", "\n### "]
        .iter()
        .filter_map(|h| section[4..].find(h))
        .min()
        .map_or(section.len(), |i| i + 4);
    let section = &section[..end];
    let rows: BTreeMap<String, String> = section
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| panel"))
        .map(|l| {
            let title = l[2..].split(" | ").next().unwrap_or("").to_string();
            (title, l.to_string())
        })
        .collect();
    let layout = layout();
    let configs = layout["configById"].as_object().unwrap();
    let titles: BTreeSet<String> = configs
        .values()
        .map(|c| c["foxglovePanelTitle"].as_str().unwrap_or("").to_string())
        .collect();
    assert_eq!(
        rows.keys().cloned().collect::<BTreeSet<_>>(),
        titles,
        "the README's table rows against the panels' titles"
    );
    for (id, cfg) in configs {
        let row = &rows[cfg["foxglovePanelTitle"].as_str().unwrap()];
        for p in shown_paths(cfg) {
            let named = p.find('.').map_or(p.as_str(), |i| &p[i..]);
            assert!(
                row.contains(named),
                "README row of {id} does not name {named}: {row}"
            );
        }
    }
}
