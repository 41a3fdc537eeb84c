//! The one place where engine errors cross into Python.
//!
//! | `tcd_core::Error` variant | Python exception |
//! |---|---|
//! | `NotFound` | `FileNotFoundError` |
//! | `Io` | `OSError` |
//! | `Corrupt`, `MissingMetadata`, `BadMetadata`, `InvalidConfig`, `BetasMismatch`, `MissingTensor`, `UnexpectedTensor`, `TensorShape`, `TensorDtype` | `tcd.exceptions.WeightsError(message, path)` |
//! | `InvalidInput` | `tcd.exceptions.InvalidInputError(message, argument)` |
//! | `ThreadPool` (and any variant a newer engine adds) | `tcd.exceptions.TcdError` |
//!
//! `WeightsError` and `InvalidInputError` subclass both `TcdError` and `ValueError`. The message is
//! always the engine's full sentence.

use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyType;
use tcd_core::Error;

/// An engine error on its way to Python (`?` converts it into a `PyErr`).
#[derive(Debug)]
pub struct PyTcdError(pub Error);

impl From<Error> for PyTcdError {
    fn from(e: Error) -> Self {
        PyTcdError(e)
    }
}

/// Shorthand for [`Error::InvalidInput`].
pub fn invalid(argument: &str, expected: impl Into<String>, received: impl Into<String>) -> Error {
    Error::invalid_input(argument, expected, received)
}

/// `tcd.exceptions.<name>`, or `None` when the package is not importable (the native module
/// loaded on its own).
fn exception_type<'py>(py: Python<'py>, name: &str) -> Option<Bound<'py, PyType>> {
    let module = py.import("tcd.exceptions").ok()?;
    module.getattr(name).ok()?.cast_into::<PyType>().ok()
}

/// `tcd.exceptions.<name>(*args)`, falling back to `fallback(message)`.
fn raise<A>(
    py: Python<'_>,
    name: &str,
    args: A,
    message: String,
    fallback: fn(String) -> PyErr,
) -> PyErr
where
    A: pyo3::PyErrArguments + Send + Sync + 'static,
{
    match exception_type(py, name) {
        Some(ty) => PyErr::from_type(ty, args),
        None => fallback(message),
    }
}

/// A bug in the binding or engine, not the caller's fault: `tcd.exceptions.TcdError`.
pub fn internal(py: Python<'_>, message: &str) -> PyErr {
    let m = format!("Internal error: {message}. Please report this.");
    raise(py, "TcdError", (m.clone(),), m, PyRuntimeError::new_err)
}

fn to_pyerr(py: Python<'_>, e: Error) -> PyErr {
    let message = e.to_string();
    match e {
        Error::NotFound { .. } => PyFileNotFoundError::new_err(message),
        Error::Io { .. } => PyOSError::new_err(message),
        Error::Corrupt { path, .. }
        | Error::MissingMetadata { path }
        | Error::BadMetadata { path, .. }
        | Error::InvalidConfig { path, .. }
        | Error::BetasMismatch { path, .. }
        | Error::MissingTensor { path, .. }
        | Error::UnexpectedTensor { path, .. }
        | Error::TensorShape { path, .. }
        | Error::TensorDtype { path, .. } => {
            let path = path.display().to_string();
            raise(
                py,
                "WeightsError",
                (message.clone(), path),
                message,
                PyValueError::new_err,
            )
        }
        Error::InvalidInput { argument, .. } => raise(
            py,
            "InvalidInputError",
            (message.clone(), argument),
            message,
            PyValueError::new_err,
        ),
        Error::ThreadPool { .. } => raise(
            py,
            "TcdError",
            (message.clone(),),
            message,
            PyRuntimeError::new_err,
        ),
        // `tcd_core::Error` is #[non_exhaustive]: a variant added later is still a TcdError
        // (weights variants keep their class through `is_weights_error`).
        other => {
            if other.is_weights_error() {
                raise(
                    py,
                    "WeightsError",
                    (message.clone(), String::new()),
                    message,
                    PyValueError::new_err,
                )
            } else {
                raise(
                    py,
                    "TcdError",
                    (message.clone(),),
                    message,
                    PyRuntimeError::new_err,
                )
            }
        }
    }
}

impl From<PyTcdError> for PyErr {
    fn from(e: PyTcdError) -> PyErr {
        Python::attach(|py| to_pyerr(py, e.0))
    }
}
