//! The one place where engine errors cross into Python, and the binding's error type [`PyTcdError`]:
//! an engine error or a Python exception, converted both ways, so that every function returns
//! [`Result`] and uses `?` on either.
//!
//! | `tcd_core::Error` variant | Python exception |
//! |---|---|
//! | `NotFound` | `FileNotFoundError` |
//! | `Io` | `OSError` |
//! | `Corrupt`, `MissingMetadata`, `BadMetadata`, `InvalidConfig`, `BetasMismatch`, `MissingTensor`, `UnexpectedTensor`, `TensorShape`, `TensorDtype`, `NonFiniteTensor`, `NotAFile` | `WeightsError(message, path)` |
//! | `InvalidInput` | `InvalidInputError(message, argument)` |
//! | `Cancelled` | `KeyboardInterrupt` (a call stopped by Ctrl-C, see `run.rs`) |
//! | `ThreadPool` (and any variant a newer engine adds) | `TcdError(message)` |
//!
//! The three exception classes are created here, in the native module, and `tcd.exceptions` re-exports
//! them: one definition, and the engine raises them without importing anything. They are plain Python
//! classes (the abi3 wheel's stable ABI cannot subclass a native exception before Python 3.12):
//! `TcdError(Exception)` from three lines of Python, `WeightsError` and `InvalidInputError` with
//! `type(name, (TcdError, ValueError), namespace)`. They keep their constructor arguments in `args`:
//! `(message, argument)` and `(message, path)`, so `str(e)` is the message (TcdError's `__str__`),
//! `.argument` / `.path` read `args[1]`, and they pickle as they are
//! (e.g. across Ray or multiprocessing workers). The message is always the engine's full sentence.

use pyo3::exceptions::{
    PyException, PyFileNotFoundError, PyKeyboardInterrupt, PyOSError, PyValueError,
};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyCFunction, PyDict, PyTuple, PyType};
use tcd_core::Error;

/// The binding's error: an engine error on its way to Python, or a Python exception already raised
/// (polars' `PyPolarsErr`). `From` both ways, so `?` takes either kind of error in a function returning
/// [`Result`], and PyO3 raises it as a Python exception (`From<PyTcdError> for PyErr`).
#[derive(Debug)]
pub(crate) enum PyTcdError {
    Engine(Error),
    Python(PyErr),
}

/// What every function of the binding returns.
pub(crate) type Result<T, E = PyTcdError> = std::result::Result<T, E>;

impl From<Error> for PyTcdError {
    fn from(e: Error) -> Self {
        PyTcdError::Engine(e)
    }
}

impl From<PyErr> for PyTcdError {
    fn from(e: PyErr) -> Self {
        PyTcdError::Python(e)
    }
}

/// Shorthand for [`Error::InvalidInput`].
pub fn invalid(argument: &str, expected: impl Into<String>, received: impl Into<String>) -> Error {
    Error::invalid_input(argument, expected, received)
}

static TCD_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// `TcdError`, the base class of every error raised by `tcd`: an `Exception` whose `str()` is its first
/// constructor argument (the others are attributes such as `argument`). Defined by a few lines of Python,
/// not a `#[pyclass]`: the stable ABI of the abi3 wheel cannot subclass a native exception before 3.12.
pub fn tcd_error(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    TCD_ERROR
        .get_or_try_init(py, || -> PyResult<Py<PyType>> {
            let namespace = PyDict::new(py);
            py.run(
                c"class TcdError(Exception):
    \"Base class of every error raised by ``tcd``.\"
    __module__ = 'tcd.exceptions'

    def __str__(self):
        return str(self.args[0]) if self.args else ''
",
                None,
                Some(&namespace),
            )?;
            Ok(namespace
                .get_item("TcdError")?
                .ok_or_else(|| PyException::new_err("TcdError was not defined"))?
                .cast_into::<PyType>()?
                .unbind())
        })
        .map(|t| t.bind(py))
}

static INVALID_INPUT_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static WEIGHTS_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// `class <name>(TcdError, ValueError)` whose `attribute` property is `args[1]` (None when absent).
fn value_error_class<'py>(
    py: Python<'py>,
    name: &str,
    doc: &str,
    attribute: &str,
) -> PyResult<Py<PyType>> {
    let second_arg =
        PyCFunction::new_closure(py, None, None, |args, _kwargs| -> PyResult<Py<PyAny>> {
            let py = args.py();
            let exc_args = args.get_item(0)?.getattr("args")?.cast_into::<PyTuple>()?;
            Ok(match exc_args.len() {
                0 | 1 => py.None(),
                _ => exc_args.get_item(1)?.unbind(),
            })
        })?;
    let builtins = py.import("builtins")?;
    let namespace = PyDict::new(py);
    namespace.set_item("__doc__", doc)?;
    namespace.set_item("__module__", "tcd.exceptions")?;
    namespace.set_item(
        attribute,
        builtins.getattr("property")?.call1((second_arg,))?,
    )?;
    let bases = (tcd_error(py)?.clone(), py.get_type::<PyValueError>());
    Ok(builtins
        .getattr("type")?
        .call1((name, bases, namespace))?
        .cast_into::<PyType>()?
        .unbind())
}

/// `InvalidInputError(message, argument=None)`.
pub fn invalid_input_error(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    INVALID_INPUT_ERROR
        .get_or_try_init(py, || {
            value_error_class(
                py,
                "InvalidInputError",
                "An argument has the wrong shape, value or content; ``argument`` names it.",
                "argument",
            )
        })
        .map(|t| t.bind(py))
}

/// `WeightsError(message, path=None)`.
pub fn weights_error(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    WEIGHTS_ERROR
        .get_or_try_init(py, || {
            value_error_class(
                py,
                "WeightsError",
                "A weight file (or model directory) is invalid; ``path`` names it.",
                "path",
            )
        })
        .map(|t| t.bind(py))
}

/// Adds the three classes to the module.
pub fn add_exceptions(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("TcdError", tcd_error(py)?)?;
    m.add("InvalidInputError", invalid_input_error(py)?)?;
    m.add("WeightsError", weights_error(py)?)?;
    Ok(())
}

/// An exception of class `ty` (or, should the class be unavailable, that failure itself).
fn raise<A: pyo3::PyErrArguments + Send + Sync + 'static>(
    ty: PyResult<&Bound<'_, PyType>>,
    args: A,
) -> PyErr {
    match ty {
        Ok(ty) => PyErr::from_type(ty.clone(), args),
        Err(e) => e,
    }
}

/// A bug in the binding or engine, not the caller's fault: `TcdError`.
pub fn internal(py: Python<'_>, message: &str) -> PyErr {
    let m = format!("Internal error: {message}. Please report this.");
    raise(tcd_error(py), (m,))
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
        | Error::TensorDtype { path, .. }
        | Error::NonFiniteTensor { path, .. }
        | Error::NotAFile { path } => {
            raise(weights_error(py), (message, path.display().to_string()))
        }
        Error::InvalidInput { argument, .. } => raise(invalid_input_error(py), (message, argument)),
        Error::Cancelled => PyKeyboardInterrupt::new_err(message),
        Error::ThreadPool { .. } => raise(tcd_error(py), (message,)),
        // `tcd_core::Error` is #[non_exhaustive]: a variant added later is still a TcdError
        // (weights variants keep their class through `is_weights_error`).
        other if other.is_weights_error() => raise(weights_error(py), (message, py.None())),
        _ => raise(tcd_error(py), (message,)),
    }
}

impl From<PyTcdError> for PyErr {
    fn from(e: PyTcdError) -> PyErr {
        match e {
            PyTcdError::Engine(e) => Python::attach(|py| to_pyerr(py, e)),
            PyTcdError::Python(e) => e,
        }
    }
}
