//! General proxies by vertex clustering (BLD §5).

use super::ProxySet;
use crate::error::{Error, Result};

impl ProxySet {
    /// General proxies by vertex clustering on cells of `cell` times the object's box.
    pub fn clustered(
        _parent: &crate::geometry::Scene,
        _objects: Option<&[u32]>,
        _cell: f32,
    ) -> Result<Self> {
        Err(Error::invalid("kind", "general proxies are not built yet"))
    }

    /// General proxies by vertex clustering with at most `target` triangles per object.
    pub fn clustered_to(
        _parent: &crate::geometry::Scene,
        _objects: Option<&[u32]>,
        _target: usize,
    ) -> Result<Self> {
        Err(Error::invalid("kind", "general proxies are not built yet"))
    }
}
