//! The channels a recording carries (angle, the two gauge pressures, the two muscle forces):
//! their column names, their order, and the values a reading of each may have. Below every
//! reader and writer of recordings, and below the effects that act on one channel.

use crate::plant::state::Measurement;

/// A measured (or simulated) output channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Channel {
    AngleDeg,
    P1Kpa,
    P2Kpa,
    F1N,
    F2N,
}

impl Channel {
    pub const ALL: [Channel; 5] = [
        Channel::AngleDeg,
        Channel::P1Kpa,
        Channel::P2Kpa,
        Channel::F1N,
        Channel::F2N,
    ];

    /// Column name in a recording.
    pub fn name(self) -> &'static str {
        match self {
            Channel::AngleDeg => "angle_deg",
            Channel::P1Kpa => "p1_kpa",
            Channel::P2Kpa => "p2_kpa",
            Channel::F1N => "f1_n",
            Channel::F2N => "f2_n",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }

    pub fn index(self) -> usize {
        self as usize
    }

    /// The value of this channel in a measurement.
    pub fn of(self, m: &Measurement) -> f64 {
        m.to_array()[self.index()]
    }

    /// The values a reading of this channel may have: wide enough for any rig of this
    /// product (and any run of the simulator on a plant file it accepts), narrow enough that
    /// an absurd value (`1e300`, a pressure in Pa, an angle in millidegrees) is refused where
    /// it is read instead of turning a fit into NaN. Returns (lo, hi, what the range means).
    pub fn plausible_range(self) -> (f64, f64, &'static str) {
        match self {
            Channel::AngleDeg => (-3600.0, 3600.0, "degrees (ten turns either way)"),
            Channel::P1Kpa | Channel::P2Kpa => (
                P_KPA_PLAUSIBLE.0,
                P_KPA_PLAUSIBLE.1,
                "kPa gauge (vacuum is -101.325 kPa, a supply at most 2000 kPa; a value in Pa?)",
            ),
            Channel::F1N | Channel::F2N => (-1.0e6, 1.0e6, "N"),
        }
    }

    /// Whether `v` lies in [`Self::plausible_range`].
    #[inline]
    pub fn is_plausible(self, v: f64) -> bool {
        let (lo, hi, _) = self.plausible_range();
        (lo..=hi).contains(&v)
    }

    /// The message for a value outside [`Self::plausible_range`].
    pub fn implausible(self, v: f64) -> String {
        let (lo, hi, what) = self.plausible_range();
        format!(
            "{} is outside the plausible range [{}, {}] {what}",
            crate::validate::Shown(v),
            crate::validate::Shown(lo),
            crate::validate::Shown(hi)
        )
    }
}

/// The gauge pressures a `p1_kpa` / `p2_kpa` reading may have [kPa] (also what `import`
/// accepts from a mapped column).
pub const P_KPA_PLAUSIBLE: (f64, f64) = (-200.0, 2500.0);
