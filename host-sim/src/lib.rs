//! host-sim: plant models, firmware-in-the-loop simulation, recordings, identification and
//! diagnosis for pneumatic-artificial-muscle joints.
//!
//! - [`plant`]: the reference 1-DOF antagonistic joint of `shared/plant/PLANT.md`.
//! - [`closed_loop`]: the firmware's control tick in the loop with the plant, scenarios.
//! - [`config`]: its TOML parameter files.
//! - [`control_compare`]: cascade vs tuned PD / PID on the set-point suite (issue 5 proof).
//! - [`sim`]: open-loop integration under zero-order-held valve inputs.
//! - [`recording`]: the CSV recording format of `shared/plant/RECORDING.md`.
//! - [`fit`]: NRMSE fit, MAE, MSE per channel.
//! - [`identify`]: force law, torque model and plant parameters from data.
//! - [`plot`]: measured vs simulated channel plots.
//! - [`diagnose_baseline`]: Elman-network residual model, the black-box baseline of the diagnosis.

pub mod arm3_io;
pub mod closed_loop;
pub mod config;
pub mod control_compare;
pub mod demo;
pub mod diagnose_baseline;
pub mod fit;
pub mod identify;
pub mod plant;
pub mod plot;
pub mod recording;
pub mod scenario_io;
pub mod sim;

pub use config::{ConfigError, PlantConfig};
pub use plant::{Measurement, Plant, PlantState, ValveInputs};
pub use recording::{Channel, Recording, RecordingError};
pub use sim::{simulate, SimError, Simulation, SolverOptions};
