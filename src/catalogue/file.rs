//! Catalogue rows as a Parquet file, and back.
//!
//! One row group of every row (a compacted catalogue of 10 000 runs is
//! about a megabyte), every column `OPTIONAL` ([`super::COLUMNS`] gives
//! its type), Snappy-compressed, with column statistics (min/max per row
//! group) that let a reader skip what a filter excludes. Strings are
//! dictionary-encoded (hosts, kinds and outcomes repeat).

use super::{CatalogueRow, ColumnType, Value, COLUMNS};
use parquet::basic::{Compression, LogicalType, Repetition, TimeUnit, Type as PhysicalType};
use parquet::column::writer::ColumnWriter;
use parquet::data_type::ByteArray;
use parquet::file::properties::WriterProperties;
use parquet::file::reader::{FileReader, SerializedFileReader};
use parquet::file::writer::SerializedFileWriter;
use parquet::record::Field;
use parquet::schema::types::Type;
use std::collections::BTreeMap;
use std::io::{self, Write};
use std::path::Path;
use std::sync::Arc;

fn pq(e: parquet::errors::ParquetError) -> io::Error {
    io::Error::other(e.to_string())
}

/// The catalogue's Parquet schema: [`COLUMNS`], all optional.
fn schema() -> parquet::errors::Result<Arc<Type>> {
    let fields = COLUMNS
        .iter()
        .map(|c| {
            let (physical, logical) = match c.column_type {
                ColumnType::TimestampUtc => (
                    PhysicalType::INT64,
                    Some(LogicalType::timestamp(true, TimeUnit::MICROS)),
                ),
                ColumnType::Text => (PhysicalType::BYTE_ARRAY, Some(LogicalType::String)),
                ColumnType::Real => (PhysicalType::DOUBLE, None),
                ColumnType::Flag => (PhysicalType::BOOLEAN, None),
                ColumnType::Unsigned => {
                    (PhysicalType::INT64, Some(LogicalType::integer(64, false)))
                }
                ColumnType::Count => (PhysicalType::INT64, None),
            };
            Type::primitive_type_builder(c.name, physical)
                .with_repetition(Repetition::OPTIONAL)
                .with_logical_type(logical)
                .build()
                .map(Arc::new)
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Arc::new(
        Type::group_type_builder("bench_catalogue")
            .with_fields(fields)
            .build()?,
    ))
}

/// Writes `rows` as one Parquet file to `w` (see the module docs).
///
/// # Errors
/// The writer's I/O error, or the Parquet writer's as
/// [`io::ErrorKind::Other`].
pub fn write_rows(rows: &[CatalogueRow], w: impl Write + Send) -> io::Result<()> {
    let cells: Vec<Vec<Value>> = rows.iter().map(CatalogueRow::values).collect();
    write_values(&cells, w)
}

/// As [`write_rows`], for rows given as their cells in [`COLUMNS`] order
/// ([`CatalogueRow::values`], or a row read back by [`read_rows`] through
/// [`in_column_order`]).
///
/// # Errors
/// As [`write_rows`]; a row whose length is not the columns' is
/// [`io::ErrorKind::InvalidInput`].
pub fn write_values(cells: &[Vec<Value>], w: impl Write + Send) -> io::Result<()> {
    if cells.iter().any(|r| r.len() != COLUMNS.len()) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "a catalogue row with another number of cells than the columns",
        ));
    }
    let props = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .set_dictionary_enabled(false)
        .set_created_by(format!("bench {}", env!("CARGO_PKG_VERSION")));
    let props = COLUMNS
        .iter()
        .filter(|c| c.column_type == ColumnType::Text)
        .fold(props, |p, c| {
            p.set_column_dictionary_enabled(parquet::schema::types::ColumnPath::from(c.name), true)
        });
    let mut writer =
        SerializedFileWriter::new(w, schema().map_err(pq)?, Arc::new(props.build())).map_err(pq)?;
    let mut rg = writer.next_row_group().map_err(pq)?;
    for (i, _) in COLUMNS.iter().enumerate() {
        let mut col = rg
            .next_column()
            .map_err(pq)?
            .ok_or_else(|| io::Error::other("the Parquet schema has fewer columns than a row"))?;
        let column = cells.iter().map(|r| &r[i]);
        let defs: Vec<i16> = column.clone().map(|v| i16::from(!v.is_null())).collect();
        match col.untyped() {
            ColumnWriter::Int64ColumnWriter(w) => {
                let v: Vec<i64> = column
                    .filter_map(|v| match v {
                        Value::TimestampUtc(x) | Value::Count(x) => *x,
                        // Parquet's unsigned INT64 holds the bits of a u64.
                        Value::Unsigned(x) => x.map(|u| u as i64),
                        _ => None,
                    })
                    .collect();
                w.write_batch(&v, Some(&defs), None).map_err(pq)?;
            }
            ColumnWriter::DoubleColumnWriter(w) => {
                let v: Vec<f64> = column
                    .filter_map(|v| match v {
                        Value::Real(x) => *x,
                        _ => None,
                    })
                    .collect();
                w.write_batch(&v, Some(&defs), None).map_err(pq)?;
            }
            ColumnWriter::BoolColumnWriter(w) => {
                let v: Vec<bool> = column
                    .filter_map(|v| match v {
                        Value::Flag(x) => *x,
                        _ => None,
                    })
                    .collect();
                w.write_batch(&v, Some(&defs), None).map_err(pq)?;
            }
            ColumnWriter::ByteArrayColumnWriter(w) => {
                let v: Vec<ByteArray> = column
                    .filter_map(|v| match v {
                        Value::Text(x) => x.as_deref().map(ByteArray::from),
                        _ => None,
                    })
                    .collect();
                w.write_batch(&v, Some(&defs), None).map_err(pq)?;
            }
            _ => return Err(io::Error::other("a catalogue column of an unexpected type")),
        }
        col.close().map_err(pq)?;
    }
    rg.close().map_err(pq)?;
    writer.close().map_err(pq)?;
    Ok(())
}

/// A row read back: column name → value.
pub type ReadRow = BTreeMap<String, Value>;

/// Reads a catalogue file (one written by [`write_rows`], or any Parquet
/// file of flat columns of these types) back, one map per row.
///
/// # Errors
/// The I/O or Parquet error, as [`io::Error`].
pub fn read_rows(path: &Path) -> io::Result<Vec<ReadRow>> {
    // A regular file within a catalogue row's limit (crate::input_file):
    // never a FIFO waited on.
    let file = crate::input_file::open(path, crate::input_file::Kind::CatalogueRow, "recordings")
        .map_err(crate::input_file::InputError::into_io)?
        .into_file();
    let reader = SerializedFileReader::new(file).map_err(pq)?;
    let types: BTreeMap<&str, ColumnType> =
        COLUMNS.iter().map(|c| (c.name, c.column_type)).collect();
    let mut out = Vec::new();
    for row in reader.get_row_iter(None).map_err(pq)? {
        let row = row.map_err(pq)?;
        let mut map = BTreeMap::new();
        for (name, field) in row.get_column_iter() {
            let kind = types.get(name.as_str()).copied();
            let value = match (field, kind) {
                (Field::Null, Some(ColumnType::TimestampUtc)) => Value::TimestampUtc(None),
                (Field::Null, Some(ColumnType::Text)) => Value::Text(None),
                (Field::Null, Some(ColumnType::Flag)) => Value::Flag(None),
                (Field::Null, Some(ColumnType::Unsigned)) => Value::Unsigned(None),
                (Field::Null, Some(ColumnType::Count)) => Value::Count(None),
                (Field::Null, _) => Value::Real(None),
                (Field::TimestampMicros(x), _) => Value::TimestampUtc(Some(*x)),
                (Field::TimestampMillis(x), _) => Value::TimestampUtc(Some(x * 1_000)),
                (Field::Str(s), _) => Value::Text(Some(s.clone())),
                (Field::Double(x), _) => Value::Real(Some(*x)),
                (Field::Float(x), _) => Value::Real(Some(f64::from(*x))),
                (Field::Bool(b), _) => Value::Flag(Some(*b)),
                (Field::ULong(u), _) => Value::Unsigned(Some(*u)),
                (Field::Long(x), _) => Value::Count(Some(*x)),
                (Field::Int(x), _) => Value::Count(Some(i64::from(*x))),
                (other, _) => {
                    return Err(io::Error::other(format!(
                        "{}: column {name} holds {other}, not a catalogue type",
                        path.display()
                    )))
                }
            };
            map.insert(name.clone(), value);
        }
        out.push(map);
    }
    Ok(out)
}

/// A row read back ([`read_rows`]) as its cells in [`COLUMNS`] order, for
/// [`write_values`]; `None` when a column is missing or of another type
/// (a file of another catalogue version).
pub fn in_column_order(row: &ReadRow) -> Option<Vec<Value>> {
    COLUMNS
        .iter()
        .map(|c| {
            row.get(c.name)
                .filter(|v| v.column_type() == c.column_type)
                .cloned()
        })
        .collect()
}

/// A row's cells by column name, as [`read_rows`] gives them.
pub fn by_name(row: &CatalogueRow) -> ReadRow {
    COLUMNS
        .iter()
        .zip(row.values())
        .map(|(c, v)| (c.name.to_string(), v))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_read_back_as_written_nulls_and_extremes_included() {
        let full = CatalogueRow {
            start_utc_us: Some(1_795_000_000_123_456),
            host: Some("lab-1".into()),
            job_kind: Some("chirp".into()),
            seed: Some(u64::MAX),
            fit_modes: Some(3),
            mode_frequency_hz: [Some(29.27), Some(81.16), None, None],
            verdict_cmp_cnmp: Some(true),
            rate_hz: Some(f64::NAN),
            recording: Some("/r/ü x.mcap".into()),
            ..CatalogueRow::default()
        };
        let rows = vec![full.clone(), CatalogueRow::default()];
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.parquet");
        write_rows(&rows, std::fs::File::create(&path).unwrap()).unwrap();
        let back = read_rows(&path).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[0], by_name(&full));
        assert_eq!(back[1], by_name(&CatalogueRow::default()));
        // NaN is written as null.
        assert_eq!(back[0]["rate_hz"], Value::Real(None));
        assert_eq!(back[0]["seed"], Value::Unsigned(Some(u64::MAX)));
    }

    #[test]
    fn no_rows_is_a_valid_empty_catalogue() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.parquet");
        write_rows(&[], std::fs::File::create(&path).unwrap()).unwrap();
        assert!(read_rows(&path).unwrap().is_empty());
    }
}
