//! Deciding whether a measured joint torque is a person pushing (as in the authors' published code: a
//! sample is an interaction when any joint exceeds its threshold; components below threshold are zeroed).

use crate::error::{check_finite, check_vector, PhriError, Result};

/// The original per-joint thresholds of the JACO2 [N·m].
pub const JACO2_THRESHOLDS: [f64; 7] = [8.0, 8.0, 8.0, 2.0, 1.0, 1.0, 1.0];

/// Per-joint thresholding with an optional bias subtracted first.
#[derive(Debug, Clone)]
pub struct InteractionDetector {
    /// |τ_j − bias_j| must exceed this to count [N·m].
    thresholds: Vec<f64>,
    /// Subtracted from the measurement (sensor offset) [N·m].
    bias: Vec<f64>,
}

impl InteractionDetector {
    pub fn new(thresholds: Vec<f64>, bias: Option<Vec<f64>>) -> Result<Self> {
        check_finite("thresholds", &thresholds)?;
        if thresholds.is_empty() {
            return Err(PhriError::invalid("thresholds", "must have one entry per joint"));
        }
        if let Some((i, v)) = thresholds.iter().enumerate().find(|(_, v)| **v < 0.0) {
            return Err(PhriError::invalid("thresholds", format!("[{i}] must be >= 0 N·m, got {v}")));
        }
        let bias = bias.unwrap_or_else(|| vec![0.0; thresholds.len()]);
        check_vector("bias", &bias, thresholds.len())?;
        Ok(InteractionDetector { thresholds, bias })
    }

    pub fn thresholds(&self) -> &[f64] {
        &self.thresholds
    }

    pub fn bias(&self) -> &[f64] {
        &self.bias
    }

    /// Writes the interaction torque u_H (bias removed, sub-threshold joints zeroed) into `u_h`
    /// and returns whether any joint exceeded its threshold.
    pub fn detect(&self, measured: &[f64], u_h: &mut [f64]) -> Result<bool> {
        let n = self.thresholds.len();
        check_vector("tau_measured", measured, n)?;
        check_vector("u_h", u_h, n)?;
        let mut any = false;
        for j in 0..n {
            let v = measured[j] - self.bias[j];
            let over = v.abs() > self.thresholds[j];
            u_h[j] = if over { v } else { 0.0 };
            any |= over;
        }
        Ok(any)
    }
}
