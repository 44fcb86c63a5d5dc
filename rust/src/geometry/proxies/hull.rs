//! Outside proxies as convex hulls (BLD §3.3, §5: the hairball's hull).

use super::ProxySet;
use crate::error::{Error, Result};

impl ProxySet {
    /// Outside proxies as the convex hull of each object (see the module docs).
    pub fn hulls(
        _parent: &crate::geometry::Scene,
        _objects: Option<&[u32]>,
        _target: Option<usize>,
    ) -> Result<Self> {
        Err(Error::invalid("kind", "hulls are not built yet"))
    }
}
