//! The D-CNN's ONNX file, read once, checked and lowered: load → validate →
//! prepare → run are distinct steps. [`ModelFile::read`] decodes the
//! protobuf, [`ModelFile::lower`] validates and lowers it to a [`Network`]
//! (the lowering itself is the private `lower` module), and a backend
//! prepares that for a frame size. Every backend runs from the same checked
//! file; the WGSL backend and the CPU reference run from the lowered layers.
//!
//! Kept apart from [`crate::network`] so that the lowered network's types
//! and the lowering that builds them do not import each other.

use std::path::{Path, PathBuf};

use prost::Message;
use tract_onnx::pb;

use crate::InferenceError;
use crate::network::Network;

/// An ONNX file decoded once at load time.
#[derive(Debug, Clone)]
pub struct ModelFile {
    pub path: PathBuf,
    pub bytes: Vec<u8>,
    pub proto: pb::ModelProto,
    /// BLAKE3 of the file, first 16 hex digits.
    pub hash: String,
}

impl ModelFile {
    /// Reads and decodes `path`; a missing, corrupt or truncated file is an
    /// error naming it.
    pub fn read(path: &Path) -> Result<Self, InferenceError> {
        let bytes = std::fs::read(path).map_err(|e| InferenceError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        Self::from_bytes(path, bytes)
    }

    pub fn from_bytes(path: &Path, bytes: Vec<u8>) -> Result<Self, InferenceError> {
        let bad = |reason: String| InferenceError::Model {
            path: path.to_path_buf(),
            reason,
        };
        if bytes.is_empty() {
            return Err(bad("the file is empty".into()));
        }
        let proto = pb::ModelProto::decode(bytes.as_slice()).map_err(|e| {
            bad(format!(
                "not a valid ONNX protobuf (corrupt or truncated): {e}"
            ))
        })?;
        if proto.graph.as_ref().is_none_or(|g| g.node.is_empty()) {
            return Err(bad(
                "no graph nodes (corrupt or truncated, or not an ONNX model)".into(),
            ));
        }
        let hash = blake3::hash(&bytes).to_hex()[..16].to_string();
        Ok(Self {
            path: path.to_path_buf(),
            bytes,
            proto,
            hash,
        })
    }

    /// Checks the signature (one 1×C×H×W float input with dynamic H and W,
    /// one 1×3×H×W output) and every operator, and lowers the graph.
    pub fn lower(&self) -> Result<Network, InferenceError> {
        crate::lower::lower(&self.proto).map_err(|reason| InferenceError::Model {
            path: self.path.clone(),
            reason,
        })
    }
}
