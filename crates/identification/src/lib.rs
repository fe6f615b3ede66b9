//! # oilfilm-identification
//!
//! From what a journal-bearing rig measures to the oil-film coefficients, as a pure library
//! (no ROS, no I/O, no clock). Frame and sign conventions are those of `oilfilm-physics`:
//! x horizontal, y up; relative motion r = journal centre minus bearing centre; the film
//! force is the force on the journal, `dF = -(K r + C r' + M r'')`.
//!
//! * [`conditioning`]: raw multiplexed DAQ samples to kinematics and the eq. 2 film force
//!   (calibration, linear-range check, deskew, zero-phase low-pass, FIR differentiation).
//! * [`excitation`]: waveforms for the two exciters and the hard limits no waveform exceeds.
//! * [`estimator`]: windowed least squares (QR/SVD, never normal equations unless the paper's
//!   method is asked for), uncertainties, refusals, and the frequency-domain cross-check.
//! * [`ascii`]: the documented, versioned text format for records from any DAQ.
//! * [`pipeline`]: a raw record and its rig in, windowed coefficients with their operating
//!   point and dimensionless forms out: the one path the CLI, the nodes and replay share.
//! * [`simulate`]: a seeded record from the simulated rig under an excitation plan.
//! * [`fft`]: the one Fourier transform (rustfft's scalar plans: the same bits on every CPU).
//! * [`simd`]: the one place that picks the CPU's vector instructions for every hot loop
//!   (results are the same bits on every instruction set).
//! * [`campaign`]: the paper's two studies on the simulated rig (coefficients against the load
//!   parameter and against the excitation amplitude), with its fits and the checks of its
//!   findings.

pub mod ascii;
pub mod campaign;
pub mod conditioning;
pub mod error;
pub mod estimator;
pub mod excitation;
pub mod fft;
pub mod pipeline;
pub mod record;
pub mod simd;
pub mod simulate;

pub use error::IdentificationError;
