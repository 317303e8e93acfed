//! The operating-point and mass-asymmetry flags that `bench chirp`,
//! `bench analyze` and `bench map --veering` share: one definition, one
//! range check in percent, one key-to-flag table.

use super::bad_input;
use bench::jobs::request::OperatingPoint;
use bench_hal::model::{ranges, Sr4dofParams};
use clap::Args;
use std::process::ExitCode;

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
    /// The operating point the flags give, if any.
    pub fn operating_point(&self) -> Option<OperatingPoint> {
        self.operating_point_m.map(OperatingPoint::Metres).or(self
            .operating_point_pct
            .map(OperatingPoint::PercentOfBeamLength))
    }

    /// The mass asymmetry the flags give (a fraction), if any.
    pub fn mass_asymmetry(&self) -> Option<f64> {
        self.mass_asymmetry
            .or(self.mass_asymmetry_pct.map(|p| p / 100.0))
    }

    /// Writes the flags into `p` (not checked: see
    /// [`Self::refuse_percent_out_of_range`] and the plant's validation).
    pub fn apply(&self, p: &mut Sr4dofParams) {
        match self.operating_point() {
            Some(OperatingPoint::Metres(m)) => p.operating_point_m = m,
            Some(OperatingPoint::PercentOfBeamLength(pct)) => {
                p.operating_point_m = pct / 100.0 * p.beam.length_m;
            }
            None => {}
        }
        if let Some(x) = self.mass_asymmetry() {
            p.mass_asymmetry = x;
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

    /// Exit 2 for a percent flag outside its key's range, said in percent
    /// (the ranges are the model's, `bench_hal::model::ranges`; the key's
    /// own check would say them as fractions and metres).
    pub fn refuse_percent_out_of_range(&self) -> Option<ExitCode> {
        if let Some(p) = self.mass_asymmetry_pct {
            let (lo, hi) = ranges::MASS_ASYMMETRY;
            if !(p.is_finite() && (lo * 100.0..=hi * 100.0).contains(&p)) {
                return Some(bad_input(format!(
                    "--mass-asymmetry-pct {p}: Δm23 must be {} % to {} % (config key plant.mass_asymmetry): the heavier secondary stage at most about 1.5 times the lighter, so the two stay a closely spaced pair (thesis §2.2.1, §5.2.1; its grid spans −8 % to +10 %)",
                    lo * 100.0,
                    hi * 100.0
                )));
            }
        }
        if let Some(p) = self.operating_point_pct {
            let max = ranges::OPERATING_POINT_OF_L * 100.0;
            if !(p.is_finite() && p.abs() <= max) {
                return Some(bad_input(format!(
                    "--operating-point-pct {p}: |Y1o| must be at most {max} % of the beam length (config key plant.operating_point_m): Eq. (2-1) is a small-rotation result, outside the model's validity beyond"
                )));
            }
        }
        None
    }

    /// The flag that set config key `key`, if one did.
    pub fn flag_for(&self, key: &str) -> Option<&'static str> {
        Some(match key {
            "plant.operating_point_m" if self.operating_point_m.is_some() => "--operating-point-m",
            "plant.operating_point_m" if self.operating_point_pct.is_some() => {
                "--operating-point-pct"
            }
            "plant.mass_asymmetry" if self.mass_asymmetry.is_some() => "--mass-asymmetry",
            "plant.mass_asymmetry" if self.mass_asymmetry_pct.is_some() => "--mass-asymmetry-pct",
            _ => return None,
        })
    }
}
