//! Bench configuration: one TOML file describes the bench (plant, actuator,
//! probe, stop, safety) and the default job parameters. SI units, with the
//! unit in every key name; unknown keys are errors.
//!
//! Loading is two steps: [`BenchConfig::from_toml`] parses (syntax, types,
//! unknown keys), [`BenchConfig::validate`] checks physics and limits. Both
//! report the dotted key and the reason.
//!
//! Layer rule: may use `input_file`.

use bench_plant::model::Sr4dofParams;
use bench_plant::sim::{ActuatorParams, ProbeParams, SimParams};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Largest config file `bench` reads, bytes (1 MiB; the shipped ones are
/// under 16 KiB): [`Kind::Config`](crate::input_file::Kind::Config)'s
/// limit.
pub const MAX_CONFIG_BYTES: u64 = crate::input_file::Kind::Config.limit_bytes();

/// The shipped bench description in the repository (the Chapter 5 bench),
/// relative to the repository root. `bench` does not read it at run time:
/// its text is built in ([`BUILTIN_CONFIG_TOML`]).
pub const DEFAULT_CONFIG: &str = "bench-config/sr4dof-ch5.toml";

/// The built-in bench description: the text of
/// `bench-config/sr4dof-ch5.toml` (the Chapter 5/6 bench of the thesis,
/// Fig 5-9: +10 % mass asymmetry, Y1o = 8 % of L), compiled into the
/// binary. It applies when no `--config` is given, so an installed `bench`
/// runs from any directory; `bench config default` prints it.
pub const BUILTIN_CONFIG_TOML: &str = include_str!("../../bench-config/sr4dof-ch5.toml");

/// How messages, summaries and recordings (`bench.config` metadata `path`)
/// name the built-in config.
pub const BUILTIN_CONFIG_NAME: &str = "built-in (sr4dof-ch5)";

/// A hint for a value that looks given in the wrong unit: a mass asymmetry
/// in percent (`10` for 10 %: `0.10` is meant; magnitudes of 1 or more,
/// i.e. at least 100 % as a fraction) or an operating point in
/// millimetres (`3` for 3 mm: `0.003` is meant). `None` unless the value is
/// outside the key's range ([`bench_plant::model::ranges`]) and the rescaled
/// one is inside it. `beam_length_m` bounds the operating point.
#[must_use]
pub fn unit_hint(key: &str, value: f64, beam_length_m: f64) -> Option<String> {
    use bench_plant::model::ranges;
    if !value.is_finite() {
        return None;
    }
    match key {
        "plant.mass_asymmetry" => {
            let (lo, hi) = ranges::MASS_ASYMMETRY;
            let inside = |x: f64| (lo..=hi).contains(&x);
            (value.abs() >= 1.0 && !inside(value) && inside(value / 100.0)).then(|| {
                format!(
                    "Δm23 is a fraction, 0.10 = 10 %: for {value} % give {}",
                    value / 100.0
                )
            })
        }
        "plant.operating_point_m" => {
            let max = ranges::OPERATING_POINT_OF_L * beam_length_m;
            (value.abs() > max && (value / 1000.0).abs() <= max).then(|| {
                format!(
                    "the operating point is in metres: {value} mm = {} m",
                    value / 1000.0
                )
            })
        }
        _ => None,
    }
}

pub mod controller;
pub mod limits;
mod sections;
mod source;
pub mod trajectory;
mod validate;

pub use controller::ControllerConfig;
pub use limits::ranges;
pub use sections::*;
pub use source::in_source_layout;
pub use trajectory::{number_or_word, ScanKind, SnapLimit, TrajectoryConfig};
pub use validate::{ticks_in, toml_error_message};

/// A configuration problem, with the file and the key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Not a config file: not a regular file (a FIFO, a device, a
    /// directory), or larger than [`MAX_CONFIG_BYTES`].
    #[error("--config {path}: {reason}")]
    NotAConfigFile {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// Syntax, type or unknown-key error (the message names the key).
    #[error("config {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message (line, column, key).
        message: String,
    },
    /// A value that cannot describe a usable bench.
    #[error("config {path}: {key}: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Dotted key.
        key: String,
        /// Why.
        reason: String,
    },
}

/// The text of the config file at `path`, read under the rules of
/// [`crate::input_file`] (a regular file, never a FIFO or a device, of at
/// most [`MAX_CONFIG_BYTES`], read with that bound): every reader of a
/// bench description given by path takes it from here.
///
/// # Errors
/// [`ConfigError::Read`] when it cannot be opened or read,
/// [`ConfigError::NotAConfigFile`] when it is not a regular file, is too
/// large or is not UTF-8.
pub fn read_text(path: &Path) -> Result<String, ConfigError> {
    use crate::input_file::{read_to_string, Kind, Problem};
    read_to_string(path, Kind::Config, "config").map_err(|e| match e.problem {
        Problem::Open(source) | Problem::Read(source) => ConfigError::Read {
            path: path.to_path_buf(),
            source,
        },
        _ => ConfigError::NotAConfigFile {
            path: path.to_path_buf(),
            reason: e.reason(),
        },
    })
}

/// The whole bench description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchConfig {
    /// Free-text description of the bench.
    #[serde(default)]
    pub description: String,
    /// The real-time loop.
    #[serde(rename = "loop")]
    pub loop_: LoopConfig,
    /// The mechanism (SR4DoF lumped model, Eq. 2-5).
    pub plant: Sr4dofParams,
    /// Amplifier and voice coil. Safety ranges: `peak_current_a` in
    /// (0, [`limits::PEAK_CURRENT_MAX_A`]] (20 A, twice the coil's rated
    /// 9.98 A peak: the supervisor clips every command to it and the I²t
    /// budget grows with its square), `continuous_current_a` in
    /// (0, `peak_current_a`].
    pub actuator: ActuatorParams,
    /// Position probe.
    pub probe: ProbeParams,
    /// Mechanical limits of the stage.
    pub stage: StageConfig,
    /// Supervisor limits.
    pub safety: SafetyConfig,
    /// What `bench chirp` plays (`[excitation]`, default an exponential
    /// sweep).
    #[serde(default)]
    pub excitation: ExcitationConfig,
    /// The swept sine (and the band and amplitude a multisine shares).
    pub chirp: ChirpConfig,
    /// The multisine of `excitation.kind = "multisine"` (absent: its
    /// defaults); refused with a sweep kind.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub multisine: Option<MultisineConfig>,
    /// FRF estimation settings.
    #[serde(default)]
    pub identification: IdentificationConfig,
    /// Simulator settings.
    #[serde(default)]
    pub sim: SimConfig,
    /// Feedback controllers by name (`[controller.slow]`, `[controller.fast]`,
    /// any `[controller.NAME]`).
    #[serde(default)]
    pub controller: BTreeMap<String, ControllerConfig>,
    /// Closed-loop step defaults.
    #[serde(default)]
    pub step: StepConfig,
    /// Which hardware runs the jobs (`[backend]`, default: the simulator).
    /// Its link timeouts and the CAN device's current ratings have safety
    /// ranges (see [`BackendConfig`]).
    #[serde(default)]
    pub backend: BackendConfig,
    /// The device emulator of `bench emulate` (`[emulator]`).
    #[serde(default)]
    pub emulator: EmulatorConfig,
    /// `bench serve` (`[daemon]`).
    #[serde(default)]
    pub daemon: DaemonConfig,
    /// The reference of `bench track` (`[trajectory]`, every key optional).
    #[serde(default, skip_serializing_if = "trajectory_is_empty")]
    pub trajectory: TrajectoryConfig,
}

fn trajectory_is_empty(t: &TrajectoryConfig) -> bool {
    *t == TrajectoryConfig::default()
}

impl BenchConfig {
    /// Reads ([`read_text`]: a regular file of at most
    /// [`MAX_CONFIG_BYTES`]) and parses a config file (no physical
    /// validation).
    ///
    /// # Errors
    /// [`ConfigError::Read`], [`ConfigError::NotAConfigFile`] or
    /// [`ConfigError::Parse`].
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::from_toml(&read_text(path)?, path)
    }

    /// Parses TOML text; `path` is only used in messages. A key an older
    /// version spelled elsewhere (`[chirp] kind`) is read where it is
    /// now ([`move_old_spellings`]), with a deprecation warning naming
    /// `path` in the log.
    ///
    /// # Errors
    /// [`ConfigError::Parse`] naming the key and position, with the
    /// parser's multi-line display (the line and a caret under the
    /// offending span; in a file with an old spelling, the key without
    /// the caret); [`ConfigError::Invalid`] when a key is set in both its
    /// old and its new spelling.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let parse = |message| ConfigError::Parse {
            path: path.to_path_buf(),
            message,
        };
        if let Ok(mut table) = text.parse::<toml::Table>() {
            let moved =
                move_old_spellings(&mut table).map_err(|(key, reason)| ConfigError::Invalid {
                    path: path.to_path_buf(),
                    key,
                    reason,
                })?;
            if let Some(note) = moved {
                tracing::warn!("{}: {note}", path.display());
                return Self::deserialize(table)
                    .map_err(|e| parse(e.to_string().trim_end().to_string()));
            }
        }
        toml::from_str(text).map_err(|e| parse(toml_error_message(text, &e)))
    }

    /// The built-in bench ([`BUILTIN_CONFIG_TOML`]), parsed (no physical
    /// validation, as [`Self::load`]).
    ///
    /// # Errors
    /// [`ConfigError::Parse`] (never for the shipped text: a unit test
    /// parses and validates it).
    pub fn builtin() -> Result<Self, ConfigError> {
        Self::from_toml(BUILTIN_CONFIG_TOML, Path::new(BUILTIN_CONFIG_NAME))
    }

    /// Checks every value for physical sense and mutual consistency.
    ///
    /// # Errors
    /// [`ConfigError::Invalid`] with the first offending key.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        self.check().map_err(|e| ConfigError::Invalid {
            path: path.to_path_buf(),
            key: e.key,
            reason: e.reason,
        })
    }

    /// The simulator's parameters.
    pub fn sim_params(&self, seed: u64) -> SimParams {
        SimParams {
            plant: self.plant,
            actuator: self.actuator,
            probe: self.probe,
            mechanical_stop_m: self.stage.mechanical_stop_m,
            seed,
        }
    }

    /// The resolved config as TOML (recorded as MCAP metadata).
    pub fn to_toml(&self) -> String {
        // Every value a config holds has a TOML form (the seed beyond
        // TOML's integers as a string): a test serialises the extremes.
        toml::to_string(self).unwrap_or_else(|e| format!("# not serialisable: {e}"))
    }

    /// SHA-256 of [`Self::to_toml`], 64 lower-case hex digits: the config
    /// hash a recording holds (`bench.config` `sha256`, `bench.run`
    /// `config_sha256`) and `bench serve --metrics` reports
    /// (`bench_build_info{config_hash}`). Two configs that resolve to the
    /// same keys and values have the same hash, whatever their comments.
    pub fn sha256_hex(&self) -> String {
        use sha2::Digest;
        sha2::Sha256::digest(self.to_toml().as_bytes())
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::validate::key_path_at;
    use super::*;

    fn shipped(name: &str) -> (BenchConfig, PathBuf) {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("bench-config")
            .join(name);
        (BenchConfig::load(&path).unwrap(), path)
    }

    #[test]
    fn the_builtin_config_is_the_shipped_chapter_5_file() {
        let (c, p) = shipped("sr4dof-ch5.toml");
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(BUILTIN_CONFIG_TOML, text);
        let b = BenchConfig::builtin().unwrap();
        b.validate(Path::new(BUILTIN_CONFIG_NAME)).unwrap();
        assert_eq!(b, c);
    }

    #[test]
    fn a_toml_error_keeps_its_caret_display_and_names_the_file() {
        let e = BenchConfig::from_toml("[loop]\nrate_hz = \"fast\"\n", Path::new("my.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("config my.toml: "), "{e}");
        // Multi-line, not joined into one line (the caret display itself
        // draws its gutter with " | ").
        assert!(e.lines().count() >= 4, "{e}");
        // The offending line, and a caret line under it.
        let lines: Vec<&str> = e.lines().collect();
        assert!(
            lines.iter().any(|l| l.contains("rate_hz = \"fast\"")),
            "{e}"
        );
        assert!(
            lines.iter().any(|l| l
                .trim_start()
                .trim_start_matches('|')
                .trim()
                .starts_with('^')),
            "{e}"
        );
    }

    #[test]
    fn a_toml_error_names_its_key_path_array_elements_included() {
        // The span of the offending value `"a"` → its key path.
        for (text, key) in [
            ("[loop]\nrate_hz = \"a\"\n", "loop.rate_hz"),
            (
                "[chirp]\nx = [\n  [1.0, 2.0],\n  [3.0, \"a\"],\n]\n",
                "chirp.x[1][1]",
            ),
            ("[c.f]\np = [\n  1.0,\n  \"a\",\n]\n", "c.f.p[1]"),
            ("[c]\nz = [{ w = 1.0 }, { w = \"a\" }]\n", "c.z[1].w"),
            ("t = { u = [0, [1, \"a\"]] }\n", "t.u[1][1]"),
        ] {
            let at = text.find("\"a\"").unwrap();
            assert_eq!(
                key_path_at(text, at..at + 3).as_deref(),
                Some(key),
                "{text}"
            );
        }
        // A syntax error has no key path.
        assert_eq!(key_path_at("[a\nb = 1", 0..1), None);
        // The message of a type error in the bench's own structure.
        let text = BUILTIN_CONFIG_TOML.replacen("f_end_hz = 500.0", "f_end_hz = [\n 1,\n]", 1);
        let e = BenchConfig::from_toml(&text, Path::new("b.toml")).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("config b.toml: chirp.f_end_hz: TOML parse error"),
            "{e}"
        );
    }

    #[test]
    fn values_in_the_wrong_unit_get_a_hint() {
        let (mut c, _) = shipped("sr4dof-ch5.toml");
        c.plant.mass_asymmetry = 10.0;
        let e = c.check().unwrap_err();
        assert_eq!(e.key, "plant.mass_asymmetry");
        assert!(
            e.reason.contains("0.10 = 10 %") && e.reason.contains("give 0.1"),
            "{}",
            e.reason
        );
        // A plausible-looking fraction out of range: no percent hint.
        c.plant.mass_asymmetry = 0.9;
        assert!(!c.check().unwrap_err().reason.contains("0.10 = 10 %"));
        c.plant.mass_asymmetry = 0.1;
        c.plant.operating_point_m = 3.0;
        let e = c.check().unwrap_err();
        assert_eq!(e.key, "plant.operating_point_m");
        assert!(e.reason.contains("3 mm = 0.003 m"), "{}", e.reason);
        // 20 % of L = 9.5 mm: 0.05 m is out of range, but 0.05 mm is not
        // what was meant either way; 50 (mm) is out of range in metres too.
        c.plant.operating_point_m = 50.0;
        assert!(!c.check().unwrap_err().reason.contains("mm ="));
    }

    #[test]
    fn shipped_configs_parse_and_validate() {
        for name in ["sr4dof-ch5.toml", "sr4dof-ch2.toml"] {
            let (c, p) = shipped(name);
            c.validate(&p).unwrap();
            // Round trip through the recorded form.
            let again = BenchConfig::from_toml(&c.to_toml(), &p).unwrap();
            assert_eq!(again, c);
        }
    }

    #[test]
    fn ch5_is_the_chapter_5_bench() {
        let (c, _) = shipped("sr4dof-ch5.toml");
        assert!((c.plant.operating_point_m / c.plant.beam.length_m - 0.08).abs() < 1e-12);
        assert!((c.plant.mass_asymmetry - 0.10).abs() < 1e-12);
        // 72 N for 1 mm (§5.1.2).
        assert!((c.plant.k4_n_per_m + c.plant.k5_n_per_m - 72e3).abs() < 1e-9);
        assert!(
            (c.actuator.peak_current_a * c.actuator.force_constant_n_per_a - 111.0).abs() < 0.1
        );
    }

    /// One default seed: no `[sim]` table and a `[sim]` table without
    /// `seed` both give 1.
    #[test]
    fn default_seed_with_and_without_the_sim_table() {
        let (c, p) = shipped("sr4dof-ch5.toml");
        let text = c.to_toml();
        let start = text.find("[sim]").unwrap();
        let end = text[start..]
            .find("\n[")
            .map_or(text.len(), |e| start + e + 1);
        let without_table = format!("{}{}", &text[..start], &text[end..]);
        let without_seed = format!("{}[sim]\n{}", &text[..start], &text[end..]);
        for t in [without_table, without_seed] {
            assert_eq!(BenchConfig::from_toml(&t, &p).unwrap().sim.seed, 1, "{t}");
        }
        assert_eq!(SimConfig::default().seed, 1);
    }

    /// Every u64 seed survives the resolved config's TOML (a campaign's
    /// cell seeds span the whole range), and its hash tells seeds apart;
    /// seeds that are no u64 are refused naming the key.
    #[test]
    fn every_seed_round_trips_through_the_resolved_config() {
        let (mut c, p) = shipped("sr4dof-ch5.toml");
        let mut hashes = std::collections::BTreeSet::new();
        for seed in [
            0,
            1,
            i64::MAX as u64,
            i64::MAX as u64 + 1,
            11_494_561_977_276_947_931,
            u64::MAX,
        ] {
            c.sim.seed = seed;
            let text = c.to_toml();
            assert!(!text.starts_with("# not serialisable"), "{seed}: {text}");
            let back = BenchConfig::from_toml(&text, &p).unwrap();
            assert_eq!(back.sim.seed, seed);
            assert_eq!(back.to_toml(), text);
            assert!(hashes.insert(c.sha256_hex()), "{seed}");
        }
        let text = c.to_toml();
        let start = text.find("[sim]").unwrap();
        for bad in [
            "-1",
            "\"-1\"",
            "\"\"",
            "\"18446744073709551616\"",
            "\"0x10\"",
            "\" 5\"",
            "\"5e3\"",
            "1.5",
            "true",
            "[1]",
        ] {
            let t = format!("{}[sim]\nseed = {bad}\n", &text[..start]);
            let err = BenchConfig::from_toml(&t, &p).unwrap_err().to_string();
            assert!(err.contains("seed"), "{bad}: {err}");
        }
    }

    #[test]
    fn unknown_key_is_named() {
        let (c, p) = shipped("sr4dof-ch5.toml");
        let text = c.to_toml().replace("[plant]", "[plant]\nm6_kg = 1.0");
        let err = BenchConfig::from_toml(&text, &p).unwrap_err().to_string();
        assert!(err.contains("m6_kg"), "{err}");
    }

    #[test]
    fn invalid_values_name_the_key() {
        let (c, p) = shipped("sr4dof-ch5.toml");
        type Mutation = Box<dyn Fn(&mut BenchConfig)>;
        let cases: Vec<(Mutation, &str)> = vec![
            (Box::new(|c| c.plant.m1_kg = 0.0), "plant.m1_kg"),
            (Box::new(|c| c.plant.k5_n_per_m = -3.0), "plant.k5_n_per_m"),
            (Box::new(|c| c.plant.m2_kg = f64::NAN), "plant.m2_kg"),
            (Box::new(|c| c.chirp.f_end_hz = 2500.0), "chirp.f_end_hz"),
            (
                Box::new(|c| c.chirp.amplitude_a = 12.0),
                "chirp.amplitude_a",
            ),
            (
                Box::new(|c| c.safety.position_limit_m = 1.5e-3),
                "safety.position_limit_m",
            ),
            (
                Box::new(|c| c.actuator.continuous_current_a = 20.0),
                "actuator.continuous_current_a",
            ),
        ];
        for (mutate, key) in cases {
            let mut bad = c.clone();
            mutate(&mut bad);
            match bad.validate(&p) {
                Err(ConfigError::Invalid { key: k, .. }) => assert_eq!(k, key),
                other => panic!("{key}: expected Invalid, got {other:?}"),
            }
        }
    }
}
