//! Logging shim (after embassy's `fmt.rs`): with the `defmt` feature the macros forward to
//! defmt; without it (host builds) they compile to nothing but still type-check their
//! arguments.
#![allow(unused_macros)]

/// One level's macro: `log_at!(info, "x={}", x)` is `defmt::info!("x={}", x)` with the
/// `defmt` feature, otherwise only borrows its arguments.
macro_rules! log_at {
    ($level:ident, $s:literal $(, $x:expr)* $(,)?) => {{
        #[cfg(feature = "defmt")]
        ::defmt::$level!($s $(, $x)*);
        #[cfg(not(feature = "defmt"))]
        let _ = ($( & $x ),*);
    }};
}

macro_rules! trace {
    ($($t:tt)*) => { log_at!(trace, $($t)*) };
}

macro_rules! debug {
    ($($t:tt)*) => { log_at!(debug, $($t)*) };
}

macro_rules! info {
    ($($t:tt)*) => { log_at!(info, $($t)*) };
}

macro_rules! warn {
    ($($t:tt)*) => { log_at!(warn, $($t)*) };
}

macro_rules! error {
    ($($t:tt)*) => { log_at!(error, $($t)*) };
}
