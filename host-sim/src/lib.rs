//! host-sim: plant models, firmware-in-the-loop simulation, recordings, identification and
//! diagnosis for pneumatic-artificial-muscle joints.
pub mod identify;
