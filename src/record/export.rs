//! Columnar export of a recording's channel (`bench export`): CSV or
//! Parquet, one column per field, for numpy / pandas.
//!
//! Every table starts with `log_time_ns` (the message's MCAP log time, ns)
//! followed by the message's fields under their recorded names, which
//! carry the unit (`t_s`, `position_m`, `current_command_a`; `tick` is a
//! count, `state` a name). `/bench/sample` is decoded into one row per
//! tick, from its protobuf blocks or the JSON messages of older recordings
//! (also those made before newer fields: those read as `NaN`); any
//! other channel (JSON, or the protobuf `/bench/envelope`) is flattened: scalar fields become columns, nested
//! objects `outer.inner` columns, and a message of equal-length arrays (the
//! FRF) one row per array element. Missing numbers are `NaN` (CSV: `NaN`).
//!
//! Parquet: one row group per 1 048 576 rows, `DOUBLE` for reals, `INT64`
//! for integers, `BOOLEAN`, UTF-8 `BYTE_ARRAY` for names. Numbers are
//! stored plain, uncompressed and without dictionaries (noise does not
//! compress, and plain pages load fastest); names dictionary-encoded.
//! pandas reads it with `pd.read_parquet(path)`.

use crate::outputs::{write_atomically, Existing};
use crate::record::proto::Envelope;
use crate::record::{decode_samples, read_messages_tolerant, TOPIC_ENVELOPE, TOPIC_SAMPLE};
use parquet::basic::{Compression, Repetition, Type as PhysicalType};
use parquet::data_type::{BoolType, ByteArray, ByteArrayType, DoubleType, Int64Type};
use parquet::file::properties::WriterProperties;
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::Type;
use serde_json::Value;
use std::collections::BTreeMap;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Rows per Parquet row group.
pub const ROW_GROUP_ROWS: usize = 1 << 20;

/// The output format (`csv`, `parquet` in a request).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum ExportFormat {
    /// Comma-separated values with a header row.
    Csv,
    /// Apache Parquet.
    Parquet,
}

impl ExportFormat {
    /// The file extension.
    pub fn extension(self) -> &'static str {
        match self {
            Self::Csv => "csv",
            Self::Parquet => "parquet",
        }
    }
}

/// One column's values.
#[derive(Debug, Clone, PartialEq)]
pub enum ColumnData {
    /// Reals (`NaN` for missing).
    F64(Vec<f64>),
    /// Integers.
    I64(Vec<i64>),
    /// Booleans.
    Bool(Vec<bool>),
    /// Names.
    Str(Vec<String>),
}

impl ColumnData {
    fn len(&self) -> usize {
        match self {
            Self::F64(v) => v.len(),
            Self::I64(v) => v.len(),
            Self::Bool(v) => v.len(),
            Self::Str(v) => v.len(),
        }
    }
}

/// A table: named columns of equal length.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Table {
    /// `(name, values)` in order.
    pub columns: Vec<(String, ColumnData)>,
}

impl Table {
    /// Rows.
    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, |c| c.1.len())
    }
}

/// Errors of the export.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The recording cannot be read or is not an MCAP file (exit 2).
    #[error("{}: {reason}", path.display())]
    Recording {
        /// The recording.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// No message on the topic (exit 2); `topics` lists those present.
    #[error("{}: no messages on {topic} (the recording has: {topics})", path.display())]
    NoTopic {
        /// The recording.
        path: PathBuf,
        /// The topic asked for.
        topic: String,
        /// The topics it has, comma-separated.
        topics: String,
    },
    /// Writing the output failed.
    #[error("{}: {source}", path.display())]
    Output {
        /// The output file.
        path: PathBuf,
        /// The error.
        source: io::Error,
    },
}

/// The bytes of the recording at `path`, read under the rules of
/// [`crate::input_file`]: a regular file of at most
/// [`Kind::Recording`](crate::input_file::Kind::Recording)'s limit.
///
/// # Errors
/// [`ExportError::Recording`] naming the file and the reason.
pub fn read_recording(path: &Path) -> Result<Vec<u8>, ExportError> {
    use crate::input_file::{read, Kind};
    read(path, Kind::Recording, "recording").map_err(|e| ExportError::Recording {
        path: path.to_path_buf(),
        reason: e.reason(),
    })
}

/// The table of `topic` in the recording at `path` (complete, or the
/// `.part` of a killed run: every completely written chunk).
///
/// # Errors
/// [`ExportError::Recording`], [`ExportError::NoTopic`].
pub fn table_of(path: &Path, topic: &str) -> Result<Table, ExportError> {
    let bytes = read_recording(path)?;
    let read = read_messages_tolerant(&bytes);
    if read.messages.is_empty() {
        return Err(ExportError::Recording {
            path: path.to_path_buf(),
            reason: match read.error {
                Some(e) => format!("not a readable MCAP recording: {e}"),
                None => "no messages: an empty recording".into(),
            },
        });
    }
    let on: Vec<&mcap::Message<'static>> = read
        .messages
        .iter()
        .filter(|m| m.channel.topic == topic)
        .collect();
    if on.is_empty() {
        let topics = read.topics();
        return Err(ExportError::NoTopic {
            path: path.to_path_buf(),
            topic: topic.to_string(),
            topics: topics.join(", "),
        });
    }
    if topic == TOPIC_SAMPLE {
        return Ok(samples_table(&on));
    }
    Ok(json_table(&on))
}

fn samples_table(msgs: &[&mcap::Message<'static>]) -> Table {
    let n = msgs.len();
    let mut log = Vec::with_capacity(n);
    let mut tick = Vec::with_capacity(n);
    let mut f: [Vec<f64>; 6] = std::array::from_fn(|_| Vec::with_capacity(n));
    let mut state = Vec::with_capacity(n);
    let mut oor = Vec::with_capacity(n);
    for (log_time, s) in msgs.iter().filter_map(|m| decode_samples(m).ok()).flatten() {
        log.push(log_time as i64);
        tick.push(s.tick as i64);
        for (col, v) in f.iter_mut().zip([
            s.t_s,
            s.wake_s,
            s.current_command_a,
            s.position_m,
            s.excitation_a,
            s.setpoint_m,
        ]) {
            col.push(v);
        }
        state.push(s.state.as_str().to_string());
        oor.push(s.out_of_range);
    }
    let [t, wake, cmd, pos, exc, set] = f;
    Table {
        columns: vec![
            ("log_time_ns".into(), ColumnData::I64(log)),
            ("tick".into(), ColumnData::I64(tick)),
            ("t_s".into(), ColumnData::F64(t)),
            ("wake_s".into(), ColumnData::F64(wake)),
            ("current_command_a".into(), ColumnData::F64(cmd)),
            ("position_m".into(), ColumnData::F64(pos)),
            ("excitation_a".into(), ColumnData::F64(exc)),
            ("setpoint_m".into(), ColumnData::F64(set)),
            ("state".into(), ColumnData::Str(state)),
            ("out_of_range".into(), ColumnData::Bool(oor)),
        ],
    }
}

/// A scalar of a flattened JSON message.
#[derive(Debug, Clone)]
enum Cell {
    Num(f64),
    Int(i64),
    Bool(bool),
    Str(String),
    Null,
}

fn flatten(prefix: &str, v: &Value, out: &mut Vec<(String, Cell)>) {
    match v {
        Value::Object(o) => {
            for (k, v) in o {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&key, v, out);
            }
        }
        Value::Number(n) => out.push((
            prefix.to_string(),
            match n.as_i64() {
                Some(i) if n.is_i64() || n.is_u64() => Cell::Int(i),
                _ => Cell::Num(n.as_f64().unwrap_or(f64::NAN)),
            },
        )),
        Value::Bool(b) => out.push((prefix.to_string(), Cell::Bool(*b))),
        Value::String(s) => out.push((prefix.to_string(), Cell::Str(s.clone()))),
        Value::Null => out.push((prefix.to_string(), Cell::Null)),
        Value::Array(_) => out.push((prefix.to_string(), Cell::Str(v.to_string()))),
    }
}

/// The rows of one message: a message whose fields are all arrays of one
/// length (the FRF) gives one row per element, any other one row.
fn rows_of(v: &Value) -> Vec<Vec<(String, Cell)>> {
    if let Value::Object(o) = v {
        let lens: Vec<usize> = o
            .values()
            .filter_map(|x| x.as_array().map(Vec::len))
            .collect();
        if !o.is_empty() && lens.len() == o.len() && lens.iter().all(|&l| l == lens[0]) {
            return (0..lens[0])
                .map(|i| {
                    let mut row = Vec::new();
                    for (k, a) in o {
                        flatten(k, &a[i], &mut row);
                    }
                    row
                })
                .collect();
        }
    }
    let mut row = Vec::new();
    flatten("", v, &mut row);
    vec![row]
}

/// A message as JSON: a JSON message as it is, a protobuf
/// `/bench/envelope` message as its fields (the state by name). `None`
/// for what does not decode.
fn value_of(m: &mcap::Message<'static>) -> Option<Value> {
    match m.channel.message_encoding.as_str() {
        "json" => serde_json::from_slice(&m.data).ok(),
        "protobuf" if m.channel.topic == TOPIC_ENVELOPE => {
            let e = <Envelope as prost::Message>::decode(&m.data[..]).ok()?;
            serde_json::to_value(e).ok()
        }
        _ => None,
    }
}

fn json_table(msgs: &[&mcap::Message<'static>]) -> Table {
    // Column order: first seen; type: reals if any real, else integers,
    // booleans or names.
    let mut order: Vec<String> = Vec::new();
    let mut rows: Vec<(u64, BTreeMap<String, Cell>)> = Vec::new();
    for m in msgs {
        let Some(v) = value_of(m) else {
            continue;
        };
        for row in rows_of(&v) {
            let mut map = BTreeMap::new();
            for (k, c) in row {
                if !order.contains(&k) {
                    order.push(k.clone());
                }
                map.insert(k, c);
            }
            rows.push((m.log_time, map));
        }
    }
    let mut columns = vec![(
        "log_time_ns".to_string(),
        ColumnData::I64(rows.iter().map(|r| r.0 as i64).collect()),
    )];
    for name in order {
        let cells: Vec<&Cell> = rows
            .iter()
            .map(|r| r.1.get(&name).unwrap_or(&Cell::Null))
            .collect();
        let any = |f: fn(&Cell) -> bool| cells.iter().any(|c| f(c));
        let data = if any(|c| matches!(c, Cell::Str(_))) {
            ColumnData::Str(
                cells
                    .iter()
                    .map(|c| match c {
                        Cell::Str(s) => s.clone(),
                        Cell::Num(x) => x.to_string(),
                        Cell::Int(i) => i.to_string(),
                        Cell::Bool(b) => b.to_string(),
                        Cell::Null => String::new(),
                    })
                    .collect(),
            )
        } else if any(|c| matches!(c, Cell::Num(_)))
            || (any(|c| matches!(c, Cell::Int(_))) && any(|c| matches!(c, Cell::Null)))
        {
            ColumnData::F64(
                cells
                    .iter()
                    .map(|c| match c {
                        Cell::Num(x) => *x,
                        Cell::Int(i) => *i as f64,
                        _ => f64::NAN,
                    })
                    .collect(),
            )
        } else if any(|c| matches!(c, Cell::Int(_))) {
            ColumnData::I64(
                cells
                    .iter()
                    .map(|c| match c {
                        Cell::Int(i) => *i,
                        _ => 0,
                    })
                    .collect(),
            )
        } else if any(|c| matches!(c, Cell::Bool(_))) {
            ColumnData::Bool(
                cells
                    .iter()
                    .map(|c| matches!(c, Cell::Bool(true)))
                    .collect(),
            )
        } else {
            ColumnData::F64(vec![f64::NAN; cells.len()])
        };
        columns.push((name, data));
    }
    Table { columns }
}

/// Writes `table` as CSV: a header of the column names, then one line per
/// row; reals in Rust's shortest round-trip form, `NaN` for missing, names
/// quoted when they hold a comma or a quote.
///
/// # Errors
/// The writer's I/O error.
pub fn write_csv(table: &Table, w: &mut impl Write) -> io::Result<()> {
    let mut w = io::BufWriter::with_capacity(1 << 20, w);
    let names: Vec<&str> = table.columns.iter().map(|c| c.0.as_str()).collect();
    writeln!(w, "{}", names.join(","))?;
    let mut line = String::new();
    for r in 0..table.rows() {
        line.clear();
        for (i, (_, c)) in table.columns.iter().enumerate() {
            if i > 0 {
                line.push(',');
            }
            use std::fmt::Write as _;
            match c {
                ColumnData::F64(v) => {
                    if v[r].is_nan() {
                        line.push_str("NaN");
                    } else {
                        let _ = write!(line, "{}", v[r]);
                    }
                }
                ColumnData::I64(v) => {
                    let _ = write!(line, "{}", v[r]);
                }
                ColumnData::Bool(v) => line.push_str(if v[r] { "true" } else { "false" }),
                ColumnData::Str(v) => {
                    if v[r].contains([',', '"', '\n']) {
                        line.push('"');
                        line.push_str(&v[r].replace('"', "\"\""));
                        line.push('"');
                    } else {
                        line.push_str(&v[r]);
                    }
                }
            }
        }
        line.push('\n');
        w.write_all(line.as_bytes())?;
    }
    w.flush()
}

/// Writes `table` as Parquet (see the module docs).
///
/// # Errors
/// The writer's I/O error, or the Parquet writer's as
/// [`io::ErrorKind::Other`].
pub fn write_parquet(table: &Table, w: impl Write + Send) -> io::Result<()> {
    let pq = |e: parquet::errors::ParquetError| io::Error::other(e.to_string());
    let fields: Vec<Arc<Type>> = table
        .columns
        .iter()
        .map(|(name, c)| {
            let (physical, utf8) = match c {
                ColumnData::F64(_) => (PhysicalType::DOUBLE, false),
                ColumnData::I64(_) => (PhysicalType::INT64, false),
                ColumnData::Bool(_) => (PhysicalType::BOOLEAN, false),
                ColumnData::Str(_) => (PhysicalType::BYTE_ARRAY, true),
            };
            let mut b =
                Type::primitive_type_builder(name, physical).with_repetition(Repetition::REQUIRED);
            if utf8 {
                b = b.with_logical_type(Some(parquet::basic::LogicalType::String));
            }
            b.build().map(Arc::new)
        })
        .collect::<Result<_, _>>()
        .map_err(pq)?;
    let schema = Arc::new(
        Type::group_type_builder("bench")
            .with_fields(fields)
            .build()
            .map_err(pq)?,
    );
    // Fastest to load: measurement noise does not compress, so numbers are
    // stored plain (no compression, no dictionary); names (the supervisor
    // state) dictionary-encoded.
    let mut props = WriterProperties::builder()
        .set_compression(Compression::UNCOMPRESSED)
        .set_dictionary_enabled(false)
        .set_created_by(format!("bench {}", env!("CARGO_PKG_VERSION")));
    for (name, c) in &table.columns {
        if matches!(c, ColumnData::Str(_)) {
            props = props.set_column_dictionary_enabled(
                parquet::schema::types::ColumnPath::from(name.as_str()),
                true,
            );
        }
    }
    let props = Arc::new(props.build());
    let mut writer = SerializedFileWriter::new(w, schema, props).map_err(pq)?;
    let rows = table.rows();
    let mut start = 0;
    while start < rows || (rows == 0 && start == 0) {
        let end = (start + ROW_GROUP_ROWS).min(rows);
        let mut rg = writer.next_row_group().map_err(pq)?;
        for (_, c) in &table.columns {
            let mut col = rg.next_column().map_err(pq)?.ok_or_else(|| {
                io::Error::other("the Parquet schema has fewer columns than the table")
            })?;
            match c {
                ColumnData::F64(v) => {
                    col.typed::<DoubleType>()
                        .write_batch(&v[start..end], None, None)
                        .map_err(pq)?;
                }
                ColumnData::I64(v) => {
                    col.typed::<Int64Type>()
                        .write_batch(&v[start..end], None, None)
                        .map_err(pq)?;
                }
                ColumnData::Bool(v) => {
                    col.typed::<BoolType>()
                        .write_batch(&v[start..end], None, None)
                        .map_err(pq)?;
                }
                ColumnData::Str(v) => {
                    let b: Vec<ByteArray> = v[start..end]
                        .iter()
                        .map(|s| ByteArray::from(s.as_str()))
                        .collect();
                    col.typed::<ByteArrayType>()
                        .write_batch(&b, None, None)
                        .map_err(pq)?;
                }
            }
            col.close().map_err(pq)?;
        }
        rg.close().map_err(pq)?;
        if rows == 0 {
            break;
        }
        start = end;
    }
    writer.close().map_err(pq)?;
    Ok(())
}

/// Exports `topic` of `recording` to `out` in `format`, atomically (a
/// temporary file renamed when complete; `existing` decides about a file
/// already at `out`). Returns the rows written.
///
/// # Errors
/// [`ExportError`].
pub fn export(
    recording: &Path,
    topic: &str,
    format: ExportFormat,
    out: &Path,
    existing: Existing,
) -> Result<usize, ExportError> {
    let table = table_of(recording, topic)?;
    write_atomically(out, existing, |f| match format {
        ExportFormat::Csv => write_csv(&table, f),
        ExportFormat::Parquet => write_parquet(&table, f),
    })
    .map_err(|source| ExportError::Output {
        path: out.to_path_buf(),
        source,
    })?;
    Ok(table.rows())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_frf_message_of_equal_arrays_is_one_row_per_line() {
        let v: Value = serde_json::json!({
            "frequency_hz": [1.0, 2.0], "coherence": [0.5, null]
        });
        let rows = rows_of(&v);
        assert_eq!(rows.len(), 2);
        assert!(matches!(rows[1][0], (ref k, Cell::Null) if k == "coherence"));
    }

    #[test]
    fn csv_quotes_names_with_commas_and_writes_nan() {
        let t = Table {
            columns: vec![
                ("x_m".into(), ColumnData::F64(vec![1.5, f64::NAN])),
                (
                    "name".into(),
                    ColumnData::Str(vec!["a,b".into(), "c".into()]),
                ),
            ],
        };
        let mut out = Vec::new();
        write_csv(&t, &mut out).unwrap();
        assert_eq!(
            String::from_utf8(out).unwrap(),
            "x_m,name\n1.5,\"a,b\"\nNaN,c\n"
        );
    }
}
