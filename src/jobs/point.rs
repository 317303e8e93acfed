//! The plant's operating point Y1o and mass asymmetry Δm23 as a job asks
//! for them: Y1o in metres or in % of the beam length L, Δm23 as a
//! fraction or in %. One conversion from % of L to metres
//! ([`percent_of_length_m`]) and one range check in percent
//! ([`PlantPoint::check`]) for every job that takes a point: `bench
//! chirp`'s local overrides, `bench analyze` and the daemon's `analyze`,
//! `bench map`'s grid and localisation points.
//!
//! Errors name the request field (`operating_point_pct`), never a flag.

use super::request::RequestError;
use bench_plant::model::{ranges, Sr4dofParams};
use serde::{Deserialize, Serialize};

/// Y1o = `pct` % of the beam length `length_m`, m: `pct / 100 · L`.
pub fn percent_of_length_m(pct: f64, length_m: f64) -> f64 {
    pct / 100.0 * length_m
}

/// The factor from % of L to metres as a campaign grid applies it to each
/// value, `v · (0.01 · L)`. It differs from [`percent_of_length_m`] in the
/// last bit for some values (3.6 % and 6.6 % of 47.5 mm), and a campaign's
/// journal matches done cells by their exact coordinates: campaigns keep
/// the factor they were started with, or a resumed campaign would run done
/// cells again.
pub fn campaign_percent_factor(length_m: f64) -> f64 {
    0.01 * length_m
}

/// An operating point Y1o, in metres or relative to the beam length L.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OperatingPoint {
    /// Y1o, m.
    Metres(f64),
    /// Y1o in % of `plant.beam.length_m`.
    PercentOfBeamLength(f64),
}

impl OperatingPoint {
    /// Y1o in metres on a beam of length `length_m`.
    pub fn metres(self, length_m: f64) -> f64 {
        match self {
            Self::Metres(m) => m,
            Self::PercentOfBeamLength(p) => percent_of_length_m(p, length_m),
        }
    }
}

/// The point of a request, each field optional: absent, the config's
/// value holds. At most one form per quantity.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantPoint {
    /// Operating point Y1o, m (`plant.operating_point_m`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub operating_point_m: Option<f64>,
    /// Operating point Y1o in % of the beam length L.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub operating_point_pct: Option<f64>,
    /// Mass asymmetry Δm23 = m2/m3 − 1 as a fraction
    /// (`plant.mass_asymmetry`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass_asymmetry: Option<f64>,
    /// Mass asymmetry Δm23 in % (10 = +10 %).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass_asymmetry_pct: Option<f64>,
}

impl PlantPoint {
    /// No field given.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// The operating point asked for, if any (metres first).
    pub fn operating_point(&self) -> Option<OperatingPoint> {
        self.operating_point_m.map(OperatingPoint::Metres).or(self
            .operating_point_pct
            .map(OperatingPoint::PercentOfBeamLength))
    }

    /// The mass asymmetry asked for, as a fraction, if any.
    pub fn mass_asymmetry(&self) -> Option<f64> {
        self.mass_asymmetry
            .or(self.mass_asymmetry_pct.map(|p| p / 100.0))
    }

    /// Checks the forms and the percent fields: one form per quantity, and
    /// each percent within its config key's range, said in percent (the
    /// ranges are the model's, [`bench_plant::model::ranges`]; the key's own
    /// check would say them as fractions and metres). The metre and
    /// fraction fields are checked with the plant they are written into.
    ///
    /// # Errors
    /// [`RequestError::Field`] naming the field.
    pub fn check(&self) -> Result<(), RequestError> {
        let field = |field: &'static str, value: f64, reason: String| RequestError::Field {
            field,
            value: value.to_string(),
            reason,
        };
        if let (Some(_), Some(p)) = (self.operating_point_m, self.operating_point_pct) {
            return Err(field(
                "operating_point_pct",
                p,
                "give operating_point_m or operating_point_pct, not both".into(),
            ));
        }
        if let (Some(_), Some(p)) = (self.mass_asymmetry, self.mass_asymmetry_pct) {
            return Err(field(
                "mass_asymmetry_pct",
                p,
                "give mass_asymmetry or mass_asymmetry_pct, not both".into(),
            ));
        }
        if let Some(p) = self.mass_asymmetry_pct {
            let (lo, hi) = ranges::MASS_ASYMMETRY;
            if !(p.is_finite() && (lo * 100.0..=hi * 100.0).contains(&p)) {
                return Err(field(
                    "mass_asymmetry_pct",
                    p,
                    format!(
                        "Δm23 must be {} % to {} % (config key plant.mass_asymmetry): the heavier secondary stage at most about 1.5 times the lighter, so the two stay a closely spaced pair (thesis §2.2.1, §5.2.1; its grid spans −8 % to +10 %)",
                        lo * 100.0,
                        hi * 100.0
                    ),
                ));
            }
        }
        if let Some(p) = self.operating_point_pct {
            let max = ranges::OPERATING_POINT_OF_L * 100.0;
            if !(p.is_finite() && p.abs() <= max) {
                return Err(field(
                    "operating_point_pct",
                    p,
                    format!(
                        "|Y1o| must be at most {max} % of the beam length (config key plant.operating_point_m): Eq. (2-1) is a small-rotation result, outside the model's validity beyond"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Writes the point into `p` (not checked: see [`Self::check`] and the
    /// plant's validation).
    pub fn apply(&self, p: &mut Sr4dofParams) {
        if let Some(op) = self.operating_point() {
            p.operating_point_m = op.metres(p.beam.length_m);
        }
        if let Some(x) = self.mass_asymmetry() {
            p.mass_asymmetry = x;
        }
    }

    /// The field that set config key `key`, if one did.
    pub fn field_for(&self, key: &str) -> Option<&'static str> {
        Some(match key {
            "plant.operating_point_m" if self.operating_point_m.is_some() => "operating_point_m",
            "plant.operating_point_m" if self.operating_point_pct.is_some() => {
                "operating_point_pct"
            }
            "plant.mass_asymmetry" if self.mass_asymmetry.is_some() => "mass_asymmetry",
            "plant.mass_asymmetry" if self.mass_asymmetry_pct.is_some() => "mass_asymmetry_pct",
            _ => return None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percent_of_l() {
        assert_eq!(percent_of_length_m(8.0, 0.0475), 0.0038);
        assert_eq!(OperatingPoint::Metres(1e-3).metres(0.0475), 1e-3);
        assert_eq!(
            OperatingPoint::PercentOfBeamLength(6.6).metres(0.0475),
            6.6 / 100.0 * 0.0475
        );
        // The campaign's factor rounds differently at 6.6 % of 47.5 mm.
        assert_ne!(
            6.6 * campaign_percent_factor(0.0475),
            percent_of_length_m(6.6, 0.0475)
        );
    }

    #[test]
    fn checks_name_the_field() {
        let field = |p: PlantPoint| match p.check() {
            Err(RequestError::Field { field, .. }) => field,
            other => panic!("{p:?}: {other:?}"),
        };
        let pct = |op: Option<f64>, dm: Option<f64>| PlantPoint {
            operating_point_pct: op,
            mass_asymmetry_pct: dm,
            ..Default::default()
        };
        assert_eq!(field(pct(Some(25.0), None)), "operating_point_pct");
        assert_eq!(field(pct(Some(f64::NAN), None)), "operating_point_pct");
        assert_eq!(field(pct(None, Some(60.0))), "mass_asymmetry_pct");
        assert_eq!(
            field(PlantPoint {
                operating_point_m: Some(1e-3),
                operating_point_pct: Some(2.0),
                ..Default::default()
            }),
            "operating_point_pct"
        );
        assert!(pct(Some(-20.0), Some(-33.0)).check().is_ok());
        let mut p = crate::config::BenchConfig::builtin().unwrap().plant;
        pct(Some(2.0), Some(10.0)).apply(&mut p);
        assert_eq!(p.operating_point_m, 2.0 / 100.0 * p.beam.length_m);
        assert_eq!(p.mass_asymmetry, 0.1);
    }
}
