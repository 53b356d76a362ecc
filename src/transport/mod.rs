//! Curved-ray transport: GRIN media and null geodesics (seed 002).
