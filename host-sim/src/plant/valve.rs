//! ISO 6358 valve flow (PLANT.md "Valves").

/// Flow characteristic of one valve: sonic conductance `C`, critical ratio `b_c` and the
/// laminar ratio `l` above which the flow falls linearly to zero at pressure ratio 1.
///
/// The linear laminar patch keeps the flow Lipschitz near ratio 1 (the pure ISO 6358
/// ellipse has an infinite slope there), which is what keeps the pressure ODE non-stiff
/// when a muscle approaches the supply or atmospheric pressure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Iso6358Valve {
    /// C [m^3 / (s Pa)], standard (ANR) volume flow per upstream absolute pressure.
    pub sonic_conductance_m3_per_s_pa: f64,
    /// b_c.
    pub critical_ratio: f64,
    /// l.
    pub laminar_ratio: f64,
    /// phi(l) / (1 - l), slope of the laminar patch (precomputed).
    laminar_slope: f64,
}

impl Iso6358Valve {
    pub fn new(
        sonic_conductance_m3_per_s_pa: f64,
        critical_ratio: f64,
        laminar_ratio: f64,
    ) -> Self {
        let mut v = Self {
            sonic_conductance_m3_per_s_pa,
            critical_ratio,
            laminar_ratio,
            laminar_slope: 0.0,
        };
        v.laminar_slope = v.subsonic_phi(laminar_ratio) / (1.0 - laminar_ratio);
        v
    }

    #[inline(always)]
    fn subsonic_phi(&self, s: f64) -> f64 {
        let x = (s - self.critical_ratio) / (1.0 - self.critical_ratio);
        (1.0 - x * x).max(0.0).sqrt()
    }

    /// Dimensionless flow function phi(s) of the pressure ratio s = p_down / p_up in [0, 1].
    #[inline(always)]
    pub fn phi(&self, s: f64) -> f64 {
        if s <= self.critical_ratio {
            1.0
        } else if s < self.laminar_ratio {
            self.subsonic_phi(s)
        } else {
            self.laminar_slope * (1.0 - s).max(0.0)
        }
    }

    /// Standard volume flow [m^3/s] from `p_up_pa` to `p_down_pa` (absolute pressures);
    /// negative when the flow goes the other way.
    #[inline(always)]
    pub fn flow_m3_s(&self, p_up_pa: f64, p_down_pa: f64) -> f64 {
        if p_up_pa >= p_down_pa {
            self.one_way(p_up_pa, p_down_pa)
        } else {
            -self.one_way(p_down_pa, p_up_pa)
        }
    }

    #[inline(always)]
    fn one_way(&self, p_up_pa: f64, p_down_pa: f64) -> f64 {
        if p_up_pa <= 0.0 {
            return 0.0;
        }
        self.sonic_conductance_m3_per_s_pa * p_up_pa * self.phi(p_down_pa / p_up_pa)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn valve() -> Iso6358Valve {
        Iso6358Valve::new(8.0e-9, 0.433, 0.999)
    }

    #[test]
    fn choked_flow_is_proportional_to_upstream_pressure() {
        let v = valve();
        let q = v.flow_m3_s(701_325.0, 101_325.0);
        assert!((q - 8.0e-9 * 701_325.0).abs() < 1e-15);
    }

    #[test]
    fn flow_is_antisymmetric_and_zero_at_equal_pressure() {
        let v = valve();
        assert_eq!(v.flow_m3_s(3e5, 3e5), 0.0);
        let a = v.flow_m3_s(5e5, 4e5);
        let b = v.flow_m3_s(4e5, 5e5);
        assert!(a > 0.0 && (a + b).abs() < 1e-18);
    }

    #[test]
    fn phi_is_continuous_at_both_breakpoints() {
        let v = valve();
        let e = 1e-12;
        assert!((v.phi(0.433 - e) - v.phi(0.433 + e)).abs() < 1e-5);
        assert!((v.phi(0.999 - e) - v.phi(0.999 + e)).abs() < 1e-6);
        assert_eq!(v.phi(1.0), 0.0);
    }
}
