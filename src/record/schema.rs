//! The JSON Schema of every channel, generated from the Rust type whose JSON
//! form the channel carries, and the one rule for non-finite numbers.
//!
//! The field descriptions are the fields' doc comments (they state units).
//! `serde_json` writes a non-finite `f64` (`NaN`, `±inf`) as `null`, since
//! JSON has no NaN; [`schema_of`] therefore declares every number as
//! `["number", "null"]`, and [`nan_if_null`] reads such a `null` back as NaN.

use schemars::generate::SchemaSettings;
use schemars::transform::{transform_subschemas, Transform};
use schemars::{JsonSchema, Schema};
use serde::{Deserialize, Deserializer};
use serde_json::Value;

/// The JSON Schema (draft 2020-12) of the JSON that `serde_json` writes for
/// a `T`: the schema of `T`'s `Serialize` form, with each field's doc comment
/// as its `description`, every `number` widened to `["number", "null"]`
/// (non-finite values are written as `null`) and the types it refers to
/// under `$defs`.
///
/// Not real-time safe (allocates); channels are registered off the tick.
pub fn schema_of<T: JsonSchema + ?Sized>() -> Value {
    SchemaSettings::draft2020_12()
        .for_serialize()
        .with_transform(NonFiniteAsNull)
        .into_generator()
        .into_root_schema_for::<T>()
        .to_value()
}

/// Deserializes an `f64` that `serde_json` may have written as `null`
/// (non-finite): `null` gives NaN. For `#[serde(deserialize_with = ...)]`
/// on the `f64` fields of records that are read back.
///
/// # Errors
/// The deserializer's error when the value is neither a number nor `null`.
pub fn nan_if_null<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Widens `"type": "number"` to `["number", "null"]` in a schema and all its
/// subschemas (see the [module docs](self)).
#[derive(Debug, Clone, Copy)]
struct NonFiniteAsNull;

impl Transform for NonFiniteAsNull {
    fn transform(&mut self, schema: &mut Schema) {
        match schema.get_mut("type") {
            Some(t @ Value::String(_)) if t == "number" => {
                *t = Value::from(vec!["number", "null"]);
            }
            Some(Value::Array(types))
                if types.iter().any(|t| t == "number") && !types.iter().any(|t| t == "null") =>
            {
                types.push(Value::from("null"));
            }
            _ => {}
        }
        transform_subschemas(self, schema);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Serialize;
    use serde_json::json;

    /// A number somewhere.
    #[derive(Serialize, Deserialize, JsonSchema)]
    struct Inner {
        /// A length, m.
        #[serde(deserialize_with = "nan_if_null")]
        x_m: f64,
    }

    /// A message.
    #[derive(Serialize, JsonSchema)]
    struct Outer {
        /// Count of something.
        n: u32,
        /// Lengths, m.
        v_m: Vec<f64>,
        /// Maybe a time, s.
        t_s: Option<f64>,
        /// Nested.
        inner: Inner,
    }

    #[test]
    fn schema_numbers_admit_null_integers_do_not() {
        let s = schema_of::<Outer>();
        assert_eq!(
            s["$schema"],
            json!("https://json-schema.org/draft/2020-12/schema")
        );
        let p = &s["properties"];
        assert_eq!(p["n"]["type"], json!("integer"));
        assert_eq!(p["v_m"]["items"]["type"], json!(["number", "null"]));
        assert_eq!(p["t_s"]["type"], json!(["number", "null"]));
        assert_eq!(p["n"]["description"], json!("Count of something."));
        let inner = &s["$defs"]["Inner"]["properties"]["x_m"];
        assert_eq!(inner["type"], json!(["number", "null"]));
        assert_eq!(inner["description"], json!("A length, m."));
    }

    #[test]
    fn null_reads_back_as_nan() {
        let v = serde_json::to_string(&Inner { x_m: f64::INFINITY }).unwrap();
        assert_eq!(v, r#"{"x_m":null}"#);
        let back: Inner = serde_json::from_str(&v).unwrap();
        assert!(back.x_m.is_nan());
        let back: Inner = serde_json::from_str(r#"{"x_m":1.5}"#).unwrap();
        assert_eq!(back.x_m, 1.5);
        assert!(serde_json::from_str::<Inner>(r#"{"x_m":"1.5"}"#).is_err());
    }
}
