//! The diagnosis catalogue: one [`Candidate`] per effect the diagnosis can name. The candidate
//! contract ([`Candidate`], [`ParamSpec`], [`Screening`], [`Setup`]) lives with the effects,
//! in [`crate::plant::effects::candidate`]; the candidates themselves live with their effects,
//! one module each under [`crate::plant::effects`]; [`catalogue`] collects them from the
//! effect registry.

pub use crate::plant::effects::candidate::{
    clamp_to, pressure_scatter, regress_pressure, Candidate, ParamSpec, Screening, Setup,
};

/// The full catalogue, in the fixed order of the effect registry
/// ([`crate::plant::effects`]).
pub fn catalogue() -> Vec<Box<dyn Candidate>> {
    crate::plant::effects::catalogue::candidates()
}
