//! The firmware in the loop: closed-loop runs of the firmware's control tick against the
//! plant, the comparison of control laws on a set-point suite, and `calibrate` (recording ->
//! torque model -> gains -> the firmware's config files).

pub mod arm3_loop;
pub mod calibrate;
pub mod closed_loop;
pub mod compare;
pub mod compare_ff;
pub mod pil;
pub mod robustness;
pub mod run_files;
pub mod tune;
