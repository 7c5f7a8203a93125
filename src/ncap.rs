//! Euro NCAP's scoring of the frontal-collision AEB tests (pure maths; docs/scorecard.md), as
//! its own 2026 rating calculator implements it: Euro-NCAP/euroncap_rating_2026 (Apache-2.0,
//! "Crash Avoidance – Frontal Collisions v1.2"), read at commit 94b1035.
//!
//! - A test point's colour comes from the relative impact speed v_rel and the car's speed
//!   (`crash_avoidance/matrix_processing.py`, `get_band_color`): the bands are intervals
//!   (lower, upper] from −∞, so green is v_rel ≤ 0 and a boundary belongs to the band *below*
//!   (exactly 10 km/h at 50 km/h is yellow). The car's speed picks a row: 10, 20, 30, 40, and 50
//!   for every speed ≥ 50 km/h. Other speeds (the 2023 grids' 35 and 45 km/h) have no row in the
//!   calculator (its look-up gives no bands): they get no colour, with that reason.
//! - Points per colour in the standard range: green 1, yellow 0.75, orange 0.5, brown 0.25, red 0
//!   (`TestPoint.predicted_score`); in the extended range anything but red is 1.
//! - The relative impact speed is rounded half up to 2 decimals (km/h) before its colour is
//!   looked up (`test_info.py`, `compute_stage_score`: `round_half_up(raw_value, 2)`).
//! - A test's standard-range score is the mean of its points (a point without a colour counts
//!   0, as the calculator's grey cells do) times its weight (`data_model.py`, `TOTAL_SCORES`):
//!   [`Test::standard_weight`]; scores are shown rounded half up to 3 decimals.
//! - The gate (`crash_avoidance/compute_score.py`, `check_general_requirements_rules`): every
//!   frontal-collision score is zeroed when a CCRs standard-range point at ≤ 20 km/h, or the CPNA
//!   point at 75 % impact location and 10 km/h, is not green.

use std::fmt;

/// A test point's colour band, best first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Colour {
    Green,
    Yellow,
    Orange,
    Brown,
    Red,
}

impl fmt::Display for Colour {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Colour::Green => "green",
            Colour::Yellow => "yellow",
            Colour::Orange => "orange",
            Colour::Brown => "brown",
            Colour::Red => "red",
        })
    }
}

/// Which part of a test's grid a point belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Range {
    Standard,
    Extended,
}

/// Why a test point has no colour.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NoColour {
    #[error("the car's speed {0} km/h has no row in Euro NCAP's 2026 bands (rows: 10, 20, 30, 40 and >= 50 km/h)")]
    NoRow(f64),
    #[error("the relative impact speed is not a number ({0})")]
    NoImpactSpeed(f64),
}

/// The Euro NCAP frontal-collision tests mjsafe encodes (docs/scorecard.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
pub enum Test {
    /// Car-to-Car Rear stationary.
    #[serde(rename = "CCRs")]
    Ccrs,
    /// Car-to-Car Rear moving.
    #[serde(rename = "CCRm")]
    Ccrm,
    /// Car-to-Car Rear braking.
    #[serde(rename = "CCRb")]
    Ccrb,
    /// Car-to-Pedestrian Nearside Adult (day).
    #[serde(rename = "CPNA")]
    Cpna,
    /// Car-to-Pedestrian Farside Adult (day).
    #[serde(rename = "CPFA")]
    Cpfa,
}

impl Test {
    /// The most points the test's standard range gives (`TOTAL_SCORES[test]["Standard"]`).
    pub fn standard_weight(self) -> f64 {
        match self {
            Test::Ccrs => 1.2,
            Test::Ccrm => 2.4,
            Test::Ccrb => 1.6,
            Test::Cpna | Test::Cpfa => 0.5,
        }
    }
}

impl fmt::Display for Test {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Test::Ccrs => "CCRs",
            Test::Ccrm => "CCRm",
            Test::Ccrb => "CCRb",
            Test::Cpna => "CPNA",
            Test::Cpfa => "CPFA",
        })
    }
}

/// `x` rounded half up to `decimals` decimals as the calculator's `numeric.round_half_up`
/// (Excel's `ROUND`): first to max(9, decimals + 4) decimals, absorbing binary noise (2.675,
/// stored just below, rounds to 2.68), then to `decimals`, ties away from zero.
pub fn round_half_up(x: f64, decimals: i32) -> f64 {
    let scale = 10f64.powi(decimals);
    let guard = 10f64.powi(9.max(decimals + 4) - decimals);
    let guarded = (x * scale * guard).round() / guard;
    guarded.round() / scale
}

/// A test's standard-range score: the mean of its points times its weight (0 without points).
pub fn test_score(test: Test, points: &[f64]) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    points.iter().sum::<f64>() / points.len() as f64 * test.standard_weight()
}

/// The upper ends (km/h) of the bands of one row, each band (previous end, this end], with the
/// last band unbounded.
fn bands(car_speed_kmh: f64) -> Option<&'static [(Colour, f64)]> {
    const INF: f64 = f64::INFINITY;
    const LOW: [(Colour, f64); 2] = [(Colour::Green, 0.0), (Colour::Red, INF)];
    const THIRTY: [(Colour, f64); 3] = [(Colour::Green, 0.0), (Colour::Brown, 10.0), (Colour::Red, INF)];
    const FORTY: [(Colour, f64); 4] = [
        (Colour::Green, 0.0),
        (Colour::Orange, 10.0),
        (Colour::Brown, 20.0),
        (Colour::Red, INF),
    ];
    const FIFTY: [(Colour, f64); 5] = [
        (Colour::Green, 0.0),
        (Colour::Yellow, 10.0),
        (Colour::Orange, 20.0),
        (Colour::Brown, 30.0),
        (Colour::Red, INF),
    ];
    if car_speed_kmh >= 50.0 {
        return Some(&FIFTY);
    }
    // (Exact row speeds, as the calculator's dictionary look-up.)
    [
        (10.0, &LOW[..]),
        (20.0, &LOW[..]),
        (30.0, &THIRTY[..]),
        (40.0, &FORTY[..]),
    ]
    .into_iter()
    .find(|(row, _)| *row == car_speed_kmh)
    .map(|(_, bands)| bands)
}

/// The colour of a test point driven at `car_speed_kmh` that hits at the relative impact speed
/// `relative_impact_kmh` (0 or less: no impact).
pub fn colour(car_speed_kmh: f64, relative_impact_kmh: f64) -> Result<Colour, NoColour> {
    let bands = bands(car_speed_kmh).ok_or(NoColour::NoRow(car_speed_kmh))?;
    if relative_impact_kmh.is_nan() {
        return Err(NoColour::NoImpactSpeed(relative_impact_kmh));
    }
    let relative_impact_kmh = round_half_up(relative_impact_kmh, 2);
    let band = bands.iter().find(|(_, upper)| relative_impact_kmh <= *upper);
    Ok(band.map_or(Colour::Red, |(colour, _)| *colour))
}

/// A point's score in its range (1 is the best).
pub fn points(colour: Colour, range: Range) -> f64 {
    match (range, colour) {
        (Range::Extended, Colour::Red) => 0.0,
        (Range::Extended, _) => 1.0,
        (Range::Standard, Colour::Green) => 1.0,
        (Range::Standard, Colour::Yellow) => 0.75,
        (Range::Standard, Colour::Orange) => 0.5,
        (Range::Standard, Colour::Brown) => 0.25,
        (Range::Standard, Colour::Red) => 0.0,
    }
}

/// The gate: whether the frontal-collision scores stand, given the colours of the CCRs
/// standard-range points at ≤ 20 km/h and of the CPNA point at 75 % and 10 km/h.
pub fn gate_passes<'a>(ccrs_up_to_20: impl IntoIterator<Item = &'a Colour>, cpna_75_at_10: Colour) -> bool {
    cpna_75_at_10 == Colour::Green && ccrs_up_to_20.into_iter().all(|&c| c == Colour::Green)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The band table of the calculator at 94b1035, boundaries included.
    #[test]
    fn colours_follow_the_calculators_half_open_bands() {
        let cases = [
            (10.0, 0.0, Colour::Green),
            (10.0, -1.0, Colour::Green),
            (10.0, 0.005, Colour::Red),
            (20.0, 5.0, Colour::Red),
            (30.0, 0.0, Colour::Green),
            (30.0, 10.0, Colour::Brown),
            (30.0, 10.005, Colour::Red),
            (30.0, 10.004, Colour::Brown),
            (40.0, 10.0, Colour::Orange),
            (40.0, 20.0, Colour::Brown),
            (40.0, 20.5, Colour::Red),
            (50.0, 10.0, Colour::Yellow),
            (50.0, 10.5, Colour::Orange),
            (50.0, 20.0, Colour::Orange),
            (50.0, 30.0, Colour::Brown),
            (50.0, 30.5, Colour::Red),
            (80.0, 25.0, Colour::Brown),
            (80.0, 80.0, Colour::Red),
        ];
        for (speed, v_rel, expected) in cases {
            assert_eq!(colour(speed, v_rel), Ok(expected), "{speed} km/h, v_rel {v_rel} km/h");
        }
    }

    #[test]
    fn speeds_without_a_row_and_missing_impact_speeds_have_no_colour() {
        assert_eq!(colour(35.0, 0.0), Err(NoColour::NoRow(35.0)));
        assert_eq!(colour(45.0, 3.0), Err(NoColour::NoRow(45.0)));
        assert!(matches!(colour(50.0, f64::NAN), Err(NoColour::NoImpactSpeed(_))));
        assert!(colour(35.0, 0.0).unwrap_err().to_string().contains("35 km/h"));
    }

    #[test]
    fn impact_speeds_are_rounded_to_two_decimals_before_the_bands() {
        assert_eq!(round_half_up(10.004, 2), 10.0);
        assert_eq!(round_half_up(10.005, 2), 10.01);
        assert_eq!(round_half_up(2.675, 2), 2.68);
        assert_eq!(round_half_up(-0.004, 2), 0.0);
        assert_eq!(round_half_up(0.0125, 3), 0.013);
        // 10.004 km/h rounds to the boundary, which belongs to the band below.
        assert_eq!(colour(50.0, 10.004), Ok(Colour::Yellow));
        assert_eq!(colour(50.0, 10.005), Ok(Colour::Orange));
        assert_eq!(colour(10.0, 0.004), Ok(Colour::Green));
    }

    #[test]
    fn a_tests_score_is_its_mean_points_times_its_weight() {
        assert_eq!(test_score(Test::Ccrm, &[1.0, 0.5]), 0.75 * 2.4);
        assert_eq!(test_score(Test::Cpna, &[0.25]), 0.125);
        assert_eq!(test_score(Test::Ccrs, &[]), 0.0);
        let total: f64 = [Test::Ccrs, Test::Ccrm, Test::Ccrb, Test::Cpna, Test::Cpfa]
            .iter()
            .map(|t| t.standard_weight())
            .sum();
        assert!((total - 6.2).abs() < 1e-12);
    }

    #[test]
    fn points_per_colour_and_the_gate() {
        let standard: Vec<f64> = [
            Colour::Green,
            Colour::Yellow,
            Colour::Orange,
            Colour::Brown,
            Colour::Red,
        ]
        .iter()
        .map(|&c| points(c, Range::Standard))
        .collect();
        assert_eq!(standard, [1.0, 0.75, 0.5, 0.25, 0.0]);
        assert_eq!(points(Colour::Brown, Range::Extended), 1.0);
        assert_eq!(points(Colour::Red, Range::Extended), 0.0);
        assert!(gate_passes(&[Colour::Green, Colour::Green], Colour::Green));
        assert!(!gate_passes(&[Colour::Green, Colour::Yellow], Colour::Green));
        assert!(!gate_passes(&[], Colour::Red));
    }
}
