//! Constraints, one file per type, sharing [`xpbd_delta`].

pub mod dihedral;
pub mod distance;

/// The XPBD update of one constraint solved once per substep (its multiplier starts at
/// zero): `dlambda = -C / (sum_k w_k |grad_k C|^2 + alpha / h^2)`.
///
/// `weighted_gradient_sq` is `sum_k w_k |grad_k C|^2`; `alpha_tilde` is the compliance
/// divided by the substep length squared. Returns `dlambda`; each particle then moves by
/// `w_k grad_k C dlambda`.
#[inline]
pub fn xpbd_delta(c: f32, weighted_gradient_sq: f32, alpha_tilde: f32) -> f32 {
    let denom = weighted_gradient_sq + alpha_tilde;
    if denom <= f32::EPSILON {
        0.0
    } else {
        -c / denom
    }
}
