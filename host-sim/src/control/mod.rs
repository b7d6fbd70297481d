//! The firmware in the loop: closed-loop runs of the firmware's control tick against the
//! plant, and the comparison of control laws on a set-point suite.

pub mod arm3_loop;
pub mod closed_loop;
pub mod compare;
pub mod compare_ff;
pub mod pil;
pub mod robustness;
pub mod run_files;
pub mod tune;
