//! What the classes of a loaded weight file, `Denoiser`, `Prior` and `Generator`, have alike: their
//! loaders (class methods, so that the stubs declare them once, on `_WeightFile`) and the getters of the
//! file and its sizes.

/// The `#[pymethods]` of a frozen pyclass `$class { inner: Arc<$model> }` over one loaded weight
/// file: `load`, `from_bytes` (`$what` names the file in their docstrings) and the getters `path`,
/// `config_json`, `kernel`, `num_features`, `num_joints`, `coords` and `obs_len`, then the class's
/// own methods, `$($methods)*`. (pyo3 takes one `#[pymethods]` block a class, hence one macro.)
macro_rules! model_methods {
    ($class:ident($model:ty, $what:literal) { $($methods:tt)* }) => {
        #[::pyo3::pymethods]
        impl $class {
            #[doc = concat!("Loads and validates a ", $what, ".")]
            #[classmethod]
            fn load(
                _cls: &::pyo3::Bound<'_, ::pyo3::types::PyType>,
                py: ::pyo3::Python<'_>,
                path: ::std::path::PathBuf,
            ) -> $crate::error::Result<Self> {
                let inner = py.detach(move || <$model as tcd_core::Network>::load(&path))?;
                Ok(Self {
                    inner: ::std::sync::Arc::new(inner),
                })
            }

            #[doc = concat!("Loads and validates the bytes of a ", $what, "; `name` names it in error messages.")]
            #[classmethod]
            fn from_bytes(
                _cls: &::pyo3::Bound<'_, ::pyo3::types::PyType>,
                py: ::pyo3::Python<'_>,
                data: Vec<u8>,
                name: ::std::path::PathBuf,
            ) -> $crate::error::Result<Self> {
                let inner = py.detach(move || <$model as tcd_core::Network>::from_bytes(&data, &name))?;
                Ok(Self {
                    inner: ::std::sync::Arc::new(inner),
                })
            }

            #[getter]
            fn path(&self) -> String {
                tcd_core::Network::path(&*self.inner).display().to_string()
            }
            /// The `tcd_config` JSON exactly as stored in the file.
            #[getter]
            fn config_json(&self) -> String {
                tcd_core::Network::config_json(&*self.inner).to_string()
            }
            /// The compute kernels this model runs (`portable`, `avx2` or `avx512`; chosen at load from
            /// `TCD_KERNEL`, default the best the CPU supports).
            #[getter]
            fn kernel(&self) -> &'static str {
                self.inner.kernel().name()
            }
            #[getter]
            fn num_features(&self) -> usize {
                tcd_core::Network::num_features(&*self.inner)
            }
            #[getter]
            fn num_joints(&self) -> usize {
                tcd_core::Network::config(&*self.inner).model.num_joints
            }
            #[getter]
            fn coords(&self) -> usize {
                tcd_core::Network::config(&*self.inner).model.coords
            }
            #[getter]
            fn obs_len(&self) -> usize {
                tcd_core::Network::obs_len(&*self.inner)
            }

            $($methods)*
        }
    };
}

pub(crate) use model_methods;
