//! BSDF referee: the closed-form Fresnel reflectance of a smooth
//! dielectric by the angle forms, written apart from `pathtrace::bsdf`'s
//! cosine form. (Quadrature and chi-square are shared: `crate::stats`.)

/// Fresnel reflectance of a smooth dielectric by the angle forms
/// `rs = -sin(i - t) / sin(i + t)`, `rp = tan(i - t) / tan(i + t)` (f64;
/// normal incidence `((n1 - n2) / (n1 + n2))^2`; 1 past the critical angle).
pub fn fresnel_angles(theta_i: f64, n1: f64, n2: f64) -> f64 {
    let st = n1 / n2 * theta_i.sin();
    if st >= 1.0 {
        return 1.0;
    }
    if theta_i == 0.0 {
        return ((n1 - n2) / (n1 + n2)).powi(2);
    }
    let tt = st.asin();
    let rs = -(theta_i - tt).sin() / (theta_i + tt).sin();
    let rp = (theta_i - tt).tan() / (theta_i + tt).tan();
    0.5 * (rs * rs + rp * rp)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresnel_angle_form_matches_normal_incidence_and_tir() {
        assert!((fresnel_angles(0.0, 1.0, 1.5) - 0.04).abs() < 1e-15);
        assert!((fresnel_angles(1e-4, 1.0, 1.5) - 0.04).abs() < 1e-8);
        assert_eq!(fresnel_angles(1.0, 1.5, 1.0), 1.0);
    }
}
