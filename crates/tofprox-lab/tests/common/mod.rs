//! Checks shared by the lab's integration tests.
use tofprox_lab::diagnose::{AddOutcome, Rms};

/// The lab's promise (docs/lab.md): after `add`, the depth error falls to within 1.3× of the same
/// recording without the hidden effect (`control`), and the fit improves.
#[track_caller]
pub fn assert_add_reaches_control(out: &AddOutcome, control: &Rms) {
    eprintln!(
        "   before {:?}\n   after  {:?}\n   control {:?}",
        out.before.rms, out.after.rms, control
    );
    assert!(out.after.rms.depth_2phase_mm <= 1.3 * control.depth_2phase_mm);
    assert!(out.after.rms.depth_4phase_mm <= 1.3 * control.depth_4phase_mm);
    assert!(out.after.fit.chi2_per_dof < out.before.fit.chi2_per_dof);
}
