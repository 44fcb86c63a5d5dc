//! Mixed proxies: per object the proxy whose guarantee holds.

use super::{ProxyOptions, ProxySet};
use crate::error::{Error, Result};

impl ProxySet {
    /// Mixed proxies (kind general).
    pub fn mixed(_parent: &crate::geometry::Scene, _options: &ProxyOptions) -> Result<Self> {
        Err(Error::invalid("kind", "mixed proxies are not built yet"))
    }
}
