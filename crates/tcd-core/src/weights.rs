//! Reading a network file (safetensors, written by `python -m training.export`), one way for every
//! network kind.
//!
//! A file holds the PyTorch `state_dict` tensors of one network, all F32 little-endian, and a
//! `__metadata__` entry [`CONFIG_KEY`] whose value is the network's JSON configuration. A kind of
//! network implements [`Network`]: how its configuration is parsed and checked, and how it builds
//! itself from that configuration, taking each tensor by name and shape from [`Weights`] where it
//! consumes it (as candle's `VarBuilder::get` does). The checks live in [`Weights::take`] (present, F32,
//! that shape, finite) and in the end of the load (no tensor left untaken), so no list of expected
//! tensors exists beside the code that reads them: [`Network::tensor_shapes`] runs the same build to
//! list them.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use safetensors::{Dtype, SafeTensors};

use crate::error::{Error, Result};
use crate::file_config::FileConfig;

/// The `__metadata__` key that holds the JSON configuration.
pub const CONFIG_KEY: &str = "tcd_config";

/// A kind of network the engine reads from a file: the denoiser, the prior forecaster (and the
/// repair fill, a prior), the MLP sample generator.
pub trait Network: Sized {
    /// Its configuration, the file's [`CONFIG_KEY`] JSON parsed.
    type Config: FileConfig;

    /// Parses the [`CONFIG_KEY`] JSON and checks it (sizes, window, schedule); `path` names the file
    /// in errors.
    fn parse_config(json: &str, path: &Path) -> Result<Self::Config> {
        let config = Self::Config::from_json(json, path)?;
        config.validate(path)?;
        Ok(config)
    }

    /// Builds the network of `source`'s configuration, taking every tensor it consumes from `weights`.
    fn build(weights: &mut Weights<'_>, source: Source<Self::Config>) -> Result<Self>;

    /// The file it was built from: its name and its configuration.
    fn source(&self) -> &Source<Self::Config>;

    /// The file the network came from (or the name given to [`Network::from_bytes`]).
    fn path(&self) -> &Path {
        &self.source().path
    }
    /// The parsed `tcd_config`.
    fn config(&self) -> &Self::Config {
        &self.source().config
    }
    /// The `tcd_config` JSON exactly as stored.
    fn config_json(&self) -> &str {
        &self.source().config_json
    }
    /// K: coordinates per frame.
    fn num_features(&self) -> usize {
        self.config().num_features()
    }
    /// Frames of the observation it reads (the last `obs_len` of a longer input).
    fn obs_len(&self) -> usize {
        self.config().obs_len()
    }

    /// Reads and validates the file at `path`. A missing file is [`Error::NotFound`], a directory
    /// [`Error::NotAFile`], an unreadable one [`Error::Io`]; everything about the content is one of
    /// the weight-file variants ([`Error::is_weights_error`]).
    fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::from_bytes(&read_file(path)?, path)
    }

    /// From the bytes of a file; `name` names it in errors.
    fn from_bytes(bytes: &[u8], name: impl AsRef<Path>) -> Result<Self> {
        let path = name.as_ref();
        let config_json = read_config_json(bytes, path)?;
        let config = Self::parse_config(&config_json, path)?;
        let file = SafeTensors::deserialize(bytes).map_err(|e| corrupt(path, e))?;
        let mut weights = Weights {
            path: path.to_path_buf(),
            file: Some(file),
            taken: Vec::new(),
        };
        let source = Source {
            path: path.to_path_buf(),
            config,
            config_json,
        };
        let network = Self::build(&mut weights, source)?;
        weights.check_all_taken()?;
        Ok(network)
    }

    /// The tensors (state_dict name, shape) a network of `config` reads, in the order it reads them:
    /// its build run on zeros (for tests and tools that write such files).
    fn tensor_shapes(config: Self::Config) -> Result<Vec<(String, Vec<usize>)>> {
        let path = PathBuf::from("(tensor shapes)");
        let mut weights = Weights {
            path: path.clone(),
            file: None,
            taken: Vec::new(),
        };
        let source = Source {
            path,
            config,
            config_json: String::new(),
        };
        Self::build(&mut weights, source)?;
        Ok(weights.taken)
    }
}

/// Where a loaded network came from: the file's name and its [`CONFIG_KEY`] configuration, parsed and
/// exactly as stored ([`Network::path`], [`Network::config`], [`Network::config_json`]).
#[derive(Clone, Debug)]
pub struct Source<C> {
    pub(crate) path: PathBuf,
    pub(crate) config: C,
    pub(crate) config_json: String,
}

/// The tensors of one file as a network's build consumes them.
pub struct Weights<'a> {
    path: PathBuf,
    /// None: no file, every tensor zeros of its shape ([`Network::tensor_shapes`]).
    file: Option<SafeTensors<'a>>,
    /// What the build took, in order.
    taken: Vec<(String, Vec<usize>)>,
}

impl Weights<'_> {
    /// The file's name, for the network's `path` and for errors.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The data (row-major) of the tensor `name`, which must be in the file, F32, of shape `shape`
    /// and finite: else the weight-file error that names it.
    pub fn take(&mut self, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
        self.taken.push((name.to_string(), shape.to_vec()));
        let Some(file) = &self.file else {
            return Ok(vec![0.0; shape.iter().product()]);
        };
        let path = || self.path.clone();
        let view = file.tensor(name).map_err(|_| Error::MissingTensor {
            path: path(),
            name: name.to_string(),
            expected: shape.to_vec(),
        })?;
        if view.dtype() != Dtype::F32 {
            return Err(Error::TensorDtype {
                path: path(),
                name: name.to_string(),
                received: view.dtype().to_string(),
            });
        }
        if view.shape() != shape {
            return Err(Error::TensorShape {
                path: path(),
                name: name.to_string(),
                expected: shape.to_vec(),
                received: view.shape().to_vec(),
            });
        }
        let data: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        if let Some((index, &value)) = data.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(Error::NonFiniteTensor {
                path: path(),
                name: name.to_string(),
                index,
                value,
            });
        }
        Ok(data)
    }

    /// A file holds exactly the tensors its network reads: the first other one (by name) is an error.
    fn check_all_taken(&self) -> Result<()> {
        let Some(file) = &self.file else {
            return Ok(());
        };
        let taken: BTreeSet<&str> = self.taken.iter().map(|(t, _)| t.as_str()).collect();
        let mut names: Vec<&str> = file.names();
        names.sort_unstable();
        match names.into_iter().find(|n| !taken.contains(n)) {
            Some(extra) => Err(Error::UnexpectedTensor {
                path: self.path.clone(),
                name: extra.to_string(),
            }),
            None => Ok(()),
        }
    }
}

/// Reads a file into memory: a missing file is [`Error::NotFound`], a directory [`Error::NotAFile`],
/// an unreadable one [`Error::Io`].
fn read_file(path: &Path) -> Result<Vec<u8>> {
    if path.is_dir() {
        return Err(Error::NotAFile {
            path: path.to_path_buf(),
        });
    }
    std::fs::read(path).map_err(|source| {
        if source.kind() == std::io::ErrorKind::NotFound {
            Error::NotFound {
                path: path.to_path_buf(),
            }
        } else {
            Error::Io {
                path: path.to_path_buf(),
                source,
            }
        }
    })
}

/// The [`CONFIG_KEY`] JSON string of a safetensors file's `__metadata__` (not yet parsed).
fn read_config_json(bytes: &[u8], path: &Path) -> Result<String> {
    let (_, metadata) = SafeTensors::read_metadata(bytes).map_err(|e| corrupt(path, e))?;
    metadata
        .metadata()
        .as_ref()
        .and_then(|m| m.get(CONFIG_KEY))
        .cloned()
        .ok_or_else(|| Error::MissingMetadata {
            path: path.to_path_buf(),
        })
}

fn corrupt(path: &Path, e: safetensors::SafeTensorError) -> Error {
    Error::Corrupt {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}
