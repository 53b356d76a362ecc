//! The judge's self-test rows: planted wrong outputs (`judge::plants`)
//! with the verdicts `TESTS/selftest/manifest.yaml` expects.

use crate::judge::plants::{
    aborts, broken_offsets, good, gradient, hangs, nan_image, non_monotone, nondeterministic,
    panics, unsupported,
};

ops! {
    "selftest.good" Any good [] "a finite image, monotone t, good offsets";
    "selftest.nan_image" Any nan_image [] "an image with one NaN";
    "selftest.non_monotone" Any non_monotone [] "t that goes back within a ray";
    "selftest.broken_offsets" Any broken_offsets [] "offsets that decrease and miss M";
    "selftest.nondeterministic" Any nondeterministic [] "an output that changes every execution";
    "selftest.gradient" Any gradient ["flip"]
        "grad of sum(x^2) (optionally sign-flipped) and its central differences";
    "selftest.panic" Any panics [] "panics";
    "selftest.abort" Any aborts [] "aborts the process";
    "selftest.hang" Any hangs [] "never returns";
    "selftest.unsupported" Any unsupported [] "reports NotSupported";
}
