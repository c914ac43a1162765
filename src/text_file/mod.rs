//! Text files as every reader of the crate reads them: line by line, with
//! stamps and fields checked, and one error type that always names the
//! file, and the line or field when there is one. Datasets, calibration
//! files and noise tables all go through here.

pub mod atomic;
pub mod error;
pub mod text;

pub use atomic::write_atomically;
pub use error::DatasetError;
