//! The view-independent half of VF: proxies (§3.1), their lit VPLs, the discs' grid and
//! the VPLs' grid with SH (eq. 1-3), built once per scene and lighting and reusable across
//! views (Python's `vc.vf.ProxyGrid`).

use std::time::Instant;

use glam::Vec3;

use super::gather::VoxelLights;
use super::grid::{disc_bounds, index_discs, Disc, GridFrame, VoxelIndex};
use super::proxies::{irradiance, place, proxy_vpls, Proxies};
use crate::error::{Error, Result};
use crate::estimators::direct::Lighting;
use crate::lights::vpl::VplSet;

/// Proxies, their VPLs and both grids.
#[derive(Clone, Debug)]
pub struct ProxyGrid {
    pub proxies: Proxies,
    /// The proxies as discs, in proxy order.
    pub discs: Vec<Disc>,
    /// Every disc in every voxel its box touches (marching).
    pub disc_index: VoxelIndex,
    /// Per disc, the key of the voxel that holds its centre (its VPLs' voxel).
    pub home: Vec<u64>,
    /// The lit sides' VPLs.
    pub vpls: VplSet,
    /// The VPLs by voxel with each voxel's SH (gathering).
    pub lights: VoxelLights,
    /// Seconds placing and lighting the proxies.
    pub proxy_seconds: f64,
    /// Seconds hashing discs and VPLs into voxels and projecting SH (Table 1's
    /// "Voxelization").
    pub voxel_seconds: f64,
}

impl ProxyGrid {
    /// Places about `proxies` proxies in `lighting.scene`, lights them by `lighting`
    /// (stream `seed`) and voxelises them into a `voxels` grid over the scene's bounds
    /// (`table_slots`: [`VoxelIndex::build`]). Deterministic for any thread count
    /// (threads: the caller's pool).
    pub fn build(
        lighting: &Lighting,
        proxies: u32,
        voxels: [u32; 3],
        table_slots: Option<u32>,
        seed: u64,
        threads: Option<usize>,
    ) -> Result<Self> {
        let scene = lighting.scene;
        if voxels.contains(&0) {
            return Err(Error::invalid(
                "voxels",
                format!("must be positive per axis, got {voxels:?}"),
            ));
        }
        let start = Instant::now();
        let placed = place(scene, proxies, seed)?;
        let e = irradiance(lighting, &placed, seed, threads)?;
        let (vpls, _) = proxy_vpls(scene, &placed, &e)?;
        let proxy_seconds = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let discs: Vec<Disc> = (0..placed.len())
            .map(|i| Disc {
                centre: placed.position[i],
                normal: placed.normal[i],
                radius: placed.radius,
            })
            .collect();
        // Discs overhang the triangles' box by up to their radius.
        let frame = GridFrame::new(disc_bounds(scene.bounds(), &discs), voxels)?;
        let disc_index = index_discs(frame, &discs, table_slots)?;
        let home = discs
            .iter()
            .map(|d| frame.key(frame.voxel_of(d.centre)))
            .collect();
        let lights = VoxelLights::build(frame, &vpls, table_slots)?;
        Ok(Self {
            proxies: placed,
            discs,
            disc_index,
            home,
            vpls,
            lights,
            proxy_seconds,
            voxel_seconds: start.elapsed().as_secs_f64(),
        })
    }

    /// The grid's frame.
    pub fn frame(&self) -> GridFrame {
        self.disc_index.frame
    }

    /// Voxels that hold a disc.
    pub fn occupied_voxels(&self) -> usize {
        self.disc_index.entries.len()
    }

    /// Voxels that hold a VPL.
    pub fn lit_voxels(&self) -> usize {
        self.lights.index.entries.len()
    }

    /// The total flux of the VPLs (W per channel).
    pub fn flux(&self) -> Vec3 {
        self.vpls.total_flux(1).as_vec3()
    }
}
