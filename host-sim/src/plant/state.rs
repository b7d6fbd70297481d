//! The plant's state and what crosses its boundary: the ODE state ([`PlantState`], the
//! effects' [`AuxState`] and its [`AuxLayout`]), the valve inputs, the sampled channels
//! ([`Measurement`]) and an external load series ([`LoadTorque`]). A leaf: it imports nothing
//! of the crate.

/// Plant state (SI, absolute pressures).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PlantState {
    /// beta.
    pub angle_rad: f64,
    /// omega.
    pub velocity_rad_s: f64,
    /// p1, absolute.
    pub p1_abs_pa: f64,
    /// p2, absolute.
    pub p2_abs_pa: f64,
}

impl PlantState {
    pub fn to_array(self) -> [f64; 4] {
        [
            self.angle_rad,
            self.velocity_rad_s,
            self.p1_abs_pa,
            self.p2_abs_pa,
        ]
    }
    pub fn from_array(a: [f64; 4]) -> Self {
        Self {
            angle_rad: a[0],
            velocity_rad_s: a[1],
            p1_abs_pa: a[2],
            p2_abs_pa: a[3],
        }
    }
}

/// The states some effects add to (beta, omega, p1, p2): the supply reservoir's pressure
/// ([`crate::plant::effects::SupplyDrop`] with `model = "reservoir"`) and the gas temperatures of the two
/// muscles ([`crate::plant::effects::ThermalChamber`]). Without those effects they stay at their initial
/// values (p_s0 and the initial temperature) and are not integrated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AuxState {
    /// Supply reservoir pressure (absolute).
    pub supply_abs_pa: f64,
    /// Gas temperature of muscles 1 and 2.
    pub gas_temperature_k: [f64; 2],
    /// An external torque on the joint [N m], held over the sample (never integrated: its
    /// rate is 0). From the plant's [`LoadTorque`] series in an open-loop replay, else 0.
    pub load_torque_nm: f64,
}

/// An external torque on the joint, one value per sample of a replay, held over the sample:
/// a load a rig measures (a torque sensor, a motor applying it), or, for one joint of an
/// arm, what the other joints and gravity do to it (`crate::diagnose::arm3`). Not part of a
/// plant file: set by the code that builds the plant for a replay.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadTorque {
    /// Torque at sample k [N m]; past the end, the last value.
    pub torque_nm: std::sync::Arc<[f64]>,
}

impl LoadTorque {
    /// The torque held over sample `k`.
    #[inline]
    pub fn at(&self, k: usize) -> f64 {
        match self.torque_nm.get(k) {
            Some(v) => *v,
            None => self.torque_nm.last().copied().unwrap_or(0.0),
        }
    }
}

/// Which [`AuxState`] components a plant integrates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AuxLayout {
    /// None: (beta, omega, p1, p2) only.
    None,
    /// The supply reservoir pressure: 5 states.
    Supply,
    /// The two gas temperatures: 6 states.
    Temperatures,
    /// Both: 7 states (reservoir, then temperatures).
    SupplyAndTemperatures,
}

impl AuxLayout {
    /// Number of auxiliary states.
    pub fn len(self) -> usize {
        match self {
            AuxLayout::None => 0,
            AuxLayout::Supply => 1,
            AuxLayout::Temperatures => 2,
            AuxLayout::SupplyAndTemperatures => 3,
        }
    }
    /// Whether there is none.
    pub fn is_empty(self) -> bool {
        self == AuxLayout::None
    }
    /// The integrated components of `a`, in ODE order (the first [`Self::len`] are used).
    pub fn pack(self, a: &AuxState) -> [f64; 3] {
        let [t1, t2] = a.gas_temperature_k;
        match self {
            AuxLayout::None => [0.0; 3],
            AuxLayout::Supply => [a.supply_abs_pa, 0.0, 0.0],
            AuxLayout::Temperatures => [t1, t2, 0.0],
            AuxLayout::SupplyAndTemperatures => [a.supply_abs_pa, t1, t2],
        }
    }
    /// `base` with the integrated components replaced by `y` (ODE order).
    pub fn unpack(self, base: &AuxState, y: &[f64]) -> AuxState {
        let mut a = *base;
        match self {
            AuxLayout::None => {}
            AuxLayout::Supply => a.supply_abs_pa = y[0],
            AuxLayout::Temperatures => a.gas_temperature_k = [y[0], y[1]],
            AuxLayout::SupplyAndTemperatures => {
                a.supply_abs_pa = y[0];
                a.gas_temperature_k = [y[1], y[2]];
            }
        }
        a
    }
}

/// Valve openings in [0, 1], held over one sample period (a PWM duty counts as opening).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ValveInputs {
    pub u_in1: f64,
    pub u_ex1: f64,
    pub u_in2: f64,
    pub u_ex2: f64,
}

impl ValveInputs {
    pub const CLOSED: Self = Self {
        u_in1: 0.0,
        u_ex1: 0.0,
        u_in2: 0.0,
        u_ex2: 0.0,
    };

    /// From the openings in column order (u_in1, u_ex1, u_in2, u_ex2).
    #[inline]
    pub fn from_openings(u: [f64; 4]) -> Self {
        Self {
            u_in1: u[0],
            u_ex1: u[1],
            u_in2: u[2],
            u_ex2: u[3],
        }
    }

    /// A differential command `m` in [-1, 1]: m > 0 opens muscle 1's inlet and muscle 2's
    /// exhaust by m (the joint turns towards muscle 1), m < 0 the other pair by -m.
    #[inline]
    pub fn antagonistic(m: f64) -> Self {
        if m >= 0.0 {
            Self::from_openings([m, 0.0, 0.0, m])
        } else {
            Self::from_openings([0.0, -m, -m, 0.0])
        }
    }
}

/// What the sensors of a recording report (PLANT.md "Measured channels").
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Measurement {
    pub angle_deg: f64,
    /// Gauge.
    pub p1_kpa: f64,
    /// Gauge.
    pub p2_kpa: f64,
    pub f1_n: f64,
    pub f2_n: f64,
}

impl Measurement {
    pub fn to_array(self) -> [f64; 5] {
        [
            self.angle_deg,
            self.p1_kpa,
            self.p2_kpa,
            self.f1_n,
            self.f2_n,
        ]
    }
}
