//! Loading and validating a TCD weight file (safetensors, produced by `python -m training.export`).
//!
//! The file holds exactly the PyTorch `state_dict` tensors of TCD_REFERENCE.md 10.1, all F32
//! little-endian, and a `__metadata__` entry [`CONFIG_KEY`] whose value is the JSON [`TcdConfig`].
//! Validation is strict: every expected tensor with its expected shape and dtype, nothing else.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use safetensors::{Dtype, SafeTensors};

use crate::config::{ModelConfig, TcdConfig};
use crate::error::{Error, Result};

/// The `__metadata__` key that holds the JSON configuration.
pub const CONFIG_KEY: &str = "tcd_config";

/// A dense row-major f32 tensor as read from the file (PyTorch's layout).
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// The tensor names and shapes a model with this configuration has, in state_dict order.
///
/// K = num_features, E = feature_embedding_dim, D = diffusion_embedding_dim, C = channels,
/// S = side_dim, F = ffn_dim. Conv1d weights keep their kernel dimension of 1.
pub fn expected_tensors(model: &ModelConfig) -> Vec<(String, Vec<usize>)> {
    let (k, e, d, c, s, f) = (
        model.num_features,
        model.feature_embedding_dim,
        model.diffusion_embedding_dim,
        model.channels,
        model.side_dim,
        model.ffn_dim,
    );
    let mut v: Vec<(String, Vec<usize>)> = vec![
        ("embed_layer.weight".into(), vec![k, e]),
        (
            "diffmodel.diffusion_embedding.projection1.weight".into(),
            vec![d, d],
        ),
        (
            "diffmodel.diffusion_embedding.projection1.bias".into(),
            vec![d],
        ),
        (
            "diffmodel.diffusion_embedding.projection2.weight".into(),
            vec![d, d],
        ),
        (
            "diffmodel.diffusion_embedding.projection2.bias".into(),
            vec![d],
        ),
        ("diffmodel.input_projection.weight".into(), vec![c, 2, 1]),
        ("diffmodel.input_projection.bias".into(), vec![c]),
        ("diffmodel.output_projection1.weight".into(), vec![c, c, 1]),
        ("diffmodel.output_projection1.bias".into(), vec![c]),
        ("diffmodel.output_projection2.weight".into(), vec![1, c, 1]),
        ("diffmodel.output_projection2.bias".into(), vec![1]),
    ];
    for i in 0..model.num_layers {
        let p = format!("diffmodel.residual_layers.{i}");
        v.push((format!("{p}.diffusion_projection.weight"), vec![c, d]));
        v.push((format!("{p}.diffusion_projection.bias"), vec![c]));
        v.push((format!("{p}.cond_projection.weight"), vec![2 * c, s, 1]));
        v.push((format!("{p}.cond_projection.bias"), vec![2 * c]));
        v.push((format!("{p}.mid_projection.weight"), vec![2 * c, c, 1]));
        v.push((format!("{p}.mid_projection.bias"), vec![2 * c]));
        v.push((format!("{p}.output_projection.weight"), vec![2 * c, c, 1]));
        v.push((format!("{p}.output_projection.bias"), vec![2 * c]));
        for t in ["time_layer", "feature_layer"] {
            let q = format!("{p}.{t}.layers.0");
            v.push((format!("{q}.self_attn.in_proj_weight"), vec![3 * c, c]));
            v.push((format!("{q}.self_attn.in_proj_bias"), vec![3 * c]));
            v.push((format!("{q}.self_attn.out_proj.weight"), vec![c, c]));
            v.push((format!("{q}.self_attn.out_proj.bias"), vec![c]));
            v.push((format!("{q}.linear1.weight"), vec![f, c]));
            v.push((format!("{q}.linear1.bias"), vec![f]));
            v.push((format!("{q}.linear2.weight"), vec![c, f]));
            v.push((format!("{q}.linear2.bias"), vec![c]));
            v.push((format!("{q}.norm1.weight"), vec![c]));
            v.push((format!("{q}.norm1.bias"), vec![c]));
            v.push((format!("{q}.norm2.weight"), vec![c]));
            v.push((format!("{q}.norm2.bias"), vec![c]));
        }
    }
    v
}

/// A validated weight file: its configuration and its tensors by state_dict name.
#[derive(Clone, Debug)]
pub struct WeightFile {
    path: PathBuf,
    config: TcdConfig,
    config_json: String,
    tensors: BTreeMap<String, Tensor>,
}

impl WeightFile {
    /// Reads and validates `path`. A missing file is [`Error::NotFound`]; an unreadable one
    /// [`Error::Io`]; everything about the content is one of the weight-file variants.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::from_bytes(&read_file(path)?, path)
    }

    /// Validates the bytes of a safetensors file; `path` only names it in errors.
    pub fn from_bytes(bytes: &[u8], path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let (config, config_json, tensors) = read_weights(
            bytes,
            &path,
            TcdConfig::from_json,
            TcdConfig::validate,
            |c| expected_tensors(&c.model),
        )?;
        Ok(WeightFile {
            path,
            config,
            config_json,
            tensors,
        })
    }

    /// Where the weights came from (or the name given to [`WeightFile::from_bytes`]).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The parsed configuration.
    pub fn config(&self) -> &TcdConfig {
        &self.config
    }

    /// The `tcd_config` JSON exactly as stored (unknown keys included).
    pub fn config_json(&self) -> &str {
        &self.config_json
    }

    /// A tensor by its state_dict name.
    pub fn tensor(&self, name: &str) -> Option<&Tensor> {
        self.tensors.get(name)
    }

    /// All tensor names, sorted.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.tensors.keys().map(String::as_str)
    }

    /// Removes and returns a tensor (used while building the model; present after validation).
    pub(crate) fn take(&mut self, name: &str) -> Result<Tensor> {
        self.tensors
            .remove(name)
            .ok_or_else(|| Error::MissingTensor {
                path: self.path.clone(),
                name: name.to_string(),
                expected: Vec::new(),
            })
    }
}

/// The validated content of a weight file's bytes (`path` names it in errors): its configuration,
/// parsed by `parse` and checked by `check`, the [`CONFIG_KEY`] JSON exactly as stored, and exactly
/// the tensors (name, shape) that `tensors` says the configuration implies. Shared by every model
/// type's `from_bytes`.
pub(crate) fn read_weights<C>(
    bytes: &[u8],
    path: &Path,
    parse: impl FnOnce(&str, &Path) -> Result<C>,
    check: impl FnOnce(&C, &Path) -> Result<()>,
    tensors: impl FnOnce(&C) -> Vec<(String, Vec<usize>)>,
) -> Result<(C, String, BTreeMap<String, Tensor>)> {
    let config_json = read_config_json(bytes, path)?;
    let config = parse(&config_json, path)?;
    check(&config, path)?;
    let tensors = read_tensors(bytes, path, &tensors(&config))?;
    Ok((config, config_json, tensors))
}

/// Moves the data of tensor `name` out of the tensors [`read_weights`] returned, as a model type's
/// `from_bytes` builds its layers. Every expected name is there with its shape (read_tensors checked
/// exactly the expected set), so the empty fallback for a missing one is never used; it spares each
/// caller an error path that cannot happen.
pub(crate) fn take_data(tensors: &mut BTreeMap<String, Tensor>, name: &str) -> Vec<f32> {
    tensors.remove(name).map(|t| t.data).unwrap_or_default()
}

/// Reads a file into memory: a missing file is [`Error::NotFound`], a directory [`Error::NotAFile`],
/// an unreadable one [`Error::Io`]. Shared by every model type's `load`.
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>> {
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
pub(crate) fn read_config_json(bytes: &[u8], path: &Path) -> Result<String> {
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

/// Exactly the tensors `expected` (name, shape) of a safetensors file, each F32 with its shape and
/// finite: anything missing, extra, of another dtype or shape, or non-finite is an error naming it.
pub(crate) fn read_tensors(
    bytes: &[u8],
    path: &Path,
    expected: &[(String, Vec<usize>)],
) -> Result<BTreeMap<String, Tensor>> {
    let st = SafeTensors::deserialize(bytes).map_err(|e| corrupt(path, e))?;
    let mut tensors = BTreeMap::new();
    for (name, shape) in expected {
        let view = st.tensor(name).map_err(|_| Error::MissingTensor {
            path: path.to_path_buf(),
            name: name.clone(),
            expected: shape.clone(),
        })?;
        if view.dtype() != Dtype::F32 {
            return Err(Error::TensorDtype {
                path: path.to_path_buf(),
                name: name.clone(),
                received: view.dtype().to_string(),
            });
        }
        if view.shape() != shape.as_slice() {
            return Err(Error::TensorShape {
                path: path.to_path_buf(),
                name: name.clone(),
                expected: shape.clone(),
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
                path: path.to_path_buf(),
                name: name.clone(),
                index,
                value,
            });
        }
        tensors.insert(
            name.clone(),
            Tensor {
                shape: shape.clone(),
                data,
            },
        );
    }
    let mut names: Vec<&str> = st.names();
    names.sort_unstable();
    if let Some(extra) = names.into_iter().find(|n| !tensors.contains_key(*n)) {
        return Err(Error::UnexpectedTensor {
            path: path.to_path_buf(),
            name: extra.to_string(),
        });
    }
    Ok(tensors)
}
