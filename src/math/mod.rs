//! The one mathematical definition of the method (METHOD.md "Representation"
//! and "Objective"): a primitive, its truncated kernel and analytic gradient
//! ([`kernel`]), the four loss terms and their gradients ([`loss`]), Adam with
//! cosine decay ([`optim`]), and the seeded random stream everything draws
//! from ([`rng`]). Every backend evaluates exactly this.

pub mod kernel;
pub mod loss;
pub mod optim;
pub mod rng;
