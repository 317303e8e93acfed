//! The operating-point and mass-asymmetry flags that `bench chirp` and
//! `bench analyze` share: declared once, flattened into each, and turned
//! into the library's [`PlantPoint`] in one step (the conversion and the
//! checks are the library's, `bench::jobs::point`).

use bench::jobs::point::PlantPoint;
use clap::Args;

#[derive(Debug, Clone, Args)]
pub(super) struct PointArgs {
    /// Operating point Y1o, m (overrides plant.operating_point_m); 3 mm is
    /// 0.003.
    #[arg(
        long,
        value_name = "M",
        allow_hyphen_values = true,
        conflicts_with = "operating_point_pct"
    )]
    pub operating_point_m: Option<f64>,
    /// Operating point Y1o in % of the beam length L.
    #[arg(long, value_name = "PERCENT", allow_hyphen_values = true)]
    pub operating_point_pct: Option<f64>,
    /// Mass asymmetry Δm23 = m2/m3 − 1 as a fraction, 0.10 = +10 %
    /// (overrides plant.mass_asymmetry); range −0.33 to 0.5.
    #[arg(
        long,
        value_name = "X",
        allow_hyphen_values = true,
        conflicts_with = "mass_asymmetry_pct"
    )]
    pub mass_asymmetry: Option<f64>,
    /// Mass asymmetry Δm23 in %, 10 = +10 % (overrides
    /// plant.mass_asymmetry); range −33 to 50.
    #[arg(long, value_name = "PERCENT", allow_hyphen_values = true)]
    pub mass_asymmetry_pct: Option<f64>,
}

impl PointArgs {
    /// The library's point: the flags one for one.
    pub fn point(&self) -> PlantPoint {
        PlantPoint {
            operating_point_m: self.operating_point_m,
            operating_point_pct: self.operating_point_pct,
            mass_asymmetry: self.mass_asymmetry,
            mass_asymmetry_pct: self.mass_asymmetry_pct,
        }
    }

    /// Which flags were given, for the local-only refusal of `--daemon`.
    pub fn given(&self) -> [(bool, &'static str); 4] {
        [
            (self.operating_point_m.is_some(), "--operating-point-m"),
            (self.operating_point_pct.is_some(), "--operating-point-pct"),
            (self.mass_asymmetry.is_some(), "--mass-asymmetry"),
            (self.mass_asymmetry_pct.is_some(), "--mass-asymmetry-pct"),
        ]
    }

    /// The flag of a point field (`operating_point_pct`), with its value
    /// for the percent fields (their messages quote it), or the flag that
    /// set config key `key` (`plant.operating_point_m`); `None` for
    /// anything else.
    pub fn flag_for(&self, key: &str) -> Option<String> {
        let point = self.point();
        let field = point.field_for(key).unwrap_or(key);
        Some(match field {
            "operating_point_m" => "--operating-point-m".into(),
            "mass_asymmetry" => "--mass-asymmetry".into(),
            "operating_point_pct" if key == field => {
                format!("--operating-point-pct {}", self.operating_point_pct?)
            }
            "mass_asymmetry_pct" if key == field => {
                format!("--mass-asymmetry-pct {}", self.mass_asymmetry_pct?)
            }
            "operating_point_pct" => "--operating-point-pct".into(),
            "mass_asymmetry_pct" => "--mass-asymmetry-pct".into(),
            _ => return None,
        })
    }
}
