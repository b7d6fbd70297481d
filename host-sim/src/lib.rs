//! host-sim: plant models, firmware-in-the-loop simulation, recordings, identification and
//! diagnosis for pneumatic-artificial-muscle joints.
//!
//! - [`plant`]: the reference 1-DOF antagonistic joint of `shared/plant/PLANT.md`, its
//!   optional effects, its TOML files ([`plant::config`]) and seed 001's 3-DOF arm.
//! - [`sim`]: open-loop integration under zero-order-held valve inputs.
//! - [`control`]: the firmware's control tick in the loop with the plant, and the comparison
//!   of control laws.
//! - [`io`]: recordings, scenarios, run outputs, plots.
//! - [`fit`]: NRMSE fit, MAE, MSE per channel.
//! - [`optimize`]: Nelder-Mead and pattern search (gain tuning, law comparison).
//! - [`identify`]: force law, torque model and plant parameters from data.
//! - [`diagnose`]: where a recording departs from the model, and which physics is missing.
//! - [`demo`]: the main job (closed-loop scenarios and a conformance replay).

pub mod control;
pub mod defaults;
pub mod demo;
pub mod demo_arm3;
pub mod diagnose;
pub mod fit;
pub mod identify;
pub mod io;
pub mod optimize;
pub mod output;
pub mod plant;
pub mod signal;
pub mod sim;
pub mod validate;

pub use io::recording::{Channel, Recording, RecordingError};
pub use plant::config::{ConfigError, PlantConfig};
pub use plant::{Measurement, Plant, PlantState, ValveInputs};
pub use sim::{simulate, SimError, Simulation, SolverOptions};
