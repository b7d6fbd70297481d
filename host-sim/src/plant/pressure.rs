//! Isothermal (Boyle-Mariotte) chamber pressure dynamics (PLANT.md "Pressure dynamics").

/// dp/dt = (p_atm Q - p dV/dt) / V, with Q the net standard volume flow into the chamber.
#[inline(always)]
pub fn pressure_rate_pa_s(
    p_atm_pa: f64,
    p_abs_pa: f64,
    net_flow_m3_s: f64,
    volume_m3: f64,
    volume_rate_m3_s: f64,
) -> f64 {
    (p_atm_pa * net_flow_m3_s - p_abs_pa * volume_rate_m3_s) / volume_m3
}
