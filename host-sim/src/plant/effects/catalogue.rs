//! The diagnosis catalogue: every registered effect's candidates, in registry order (the one
//! list of [`super`], `effect_list!`).

use crate::plant::effects::candidate::{Candidate, EffectCandidates};

macro_rules! catalogue_of {
    ($( $(#[$attr:meta])* $module:ident :: $ty:ident ),* $(,)?) => {
        /// The diagnosis catalogue: every registered effect's candidates, in registry order.
        pub fn candidates() -> Vec<Box<dyn Candidate>> {
            let mut v: Vec<Box<dyn Candidate>> = Vec::new();
            $( $(#[$attr])* v.extend(<super::$ty as EffectCandidates>::candidates()); )*
            v
        }
    };
}

effect_list!(catalogue_of);
