//! Differentiable emission–absorption volume rendering (seed 000): fields,
//! `f_samp`, `f_int`, `f_img`, `f_fused`, `f_diff`.
