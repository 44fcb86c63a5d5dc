//! Inside proxies: inscribed spheres of watertight objects (BLD §3.4, §5).

use super::ProxySet;
use crate::error::{Error, Result};

impl ProxySet {
    /// Inside proxies: `count` inscribed spheres per watertight object.
    pub fn inscribed(
        _parent: &crate::geometry::Scene,
        _objects: Option<&[u32]>,
        _count: usize,
    ) -> Result<Self> {
        Err(Error::invalid("kind", "inside proxies are not built yet"))
    }
}
