//! Writing a scene back in the file's own terms: the parts of a scene as
//! the TOML a file gives (so an edited scene is validated as a file is),
//! and its `[[occluder]]` tables for a tool that moves occluders.

use super::*;

/// A count in the file's integer type; one too large for it stays too large.
pub(super) fn count(n: usize) -> i64 {
    i64::try_from(n).unwrap_or(i64::MAX)
}

pub(super) fn array(v: Vec3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

impl From<SceneParts> for RawFile {
    fn from(p: SceneParts) -> Self {
        let (w, s) = (p.wall.plane, p.hidden.plane);
        let (brdf, sampling, left_out) = (p.wall.brdf, p.wall.sampling, p.left_out);
        let mut polarizer = toml::Table::new();
        polarizer.insert("model".into(), p.polarizer.name().into());
        RawFile {
            wall: RawWall {
                center: array(w.center),
                normal: array(w.normal),
                u_axis: array(w.u),
                size: w.size,
                grid: [count(w.grid.nu), count(w.grid.nv)],
                supersample: (!left_out.wall_supersample || w.supersample != 1)
                    .then(|| count(w.supersample)),
                roughness: brdf.alpha,
                ior: brdf.eta,
                ks: brdf.ks,
                kd: brdf.kd,
                diffuse: Some(brdf.diffuse.name().into()),
                sampling: (!left_out.sampling || sampling != WallSampling::default())
                    .then(|| sampling.name().into()),
            },
            scene: RawScenePlane {
                center: array(s.center),
                normal: array(s.normal),
                u_axis: array(s.u),
                size: s.size,
                grid: [count(s.grid.nu), count(s.grid.nv)],
                supersample: (!left_out.scene_supersample || s.supersample != 1)
                    .then(|| count(s.supersample)),
                emitter: p.hidden.emitter,
                lobe: p.hidden.lobe,
                polarization: p.hidden.polarization.map(array),
                shadows: (p.hidden.shadows != ShadowModel::Auto).then_some(p.hidden.shadows),
            },
            pose: p
                .poses
                .into_iter()
                .map(|pose| RawPose {
                    name: pose.name,
                    camera: array(pose.camera),
                    polarizer_deg: pose
                        .mosaic
                        .is_none()
                        .then(|| pose.analyzers.iter().map(|a| a.angle_deg).collect()),
                    analyzer: pose.mosaic.map(|_| "mosaic".to_string()),
                    sensor_deg: pose.mosaic.map(|m| m.sensor_deg),
                    extinction: pose.mosaic.and_then(|m| m.extinction),
                    layout: pose.mosaic.map(|m| m.layout.name().to_string()),
                    homography: pose.homography.map(|h| h.matrix()),
                    region: pose.frame.map(|f| f.region.map(i64::from)),
                    binning: pose.frame.map(|f| f.binning.map(i64::from)),
                })
                .collect(),
            occluder: p.occluders.into_iter().map(raw_occluder).collect(),
            polarizer: Some(polarizer),
        }
    }
}

/// An occluder in the file's terms: a rect's or sphere's keys, a mesh's
/// keys as written (with its triangles kept).
pub(super) fn raw_occluder(o: Occluder) -> RawOccluder {
    match o {
        Occluder::Rect {
            center,
            half_u,
            half_v,
        } => RawOccluder {
            rect: Some(RawRect {
                center: array(center),
                half_u: array(half_u),
                half_v: array(half_v),
            }),
            ..RawOccluder::default()
        },
        Occluder::Sphere { center, radius } => RawOccluder {
            sphere: Some(RawSphere {
                center: array(center),
                radius,
            }),
            ..RawOccluder::default()
        },
        Occluder::Mesh(mesh) => RawOccluder {
            mesh: Some(mesh.source().path.clone()),
            scale: mesh.source().scale,
            offset: mesh.source().offset,
            loaded: Some(mesh),
            ..RawOccluder::default()
        },
    }
}

impl Scene {
    /// The scene's `[[occluder]]` entries as a scene file writes them (a
    /// rect's or sphere's keys; a mesh's `mesh`, `scale` and `offset`), each
    /// mesh path replaced by what `path` makes of the path as written.
    ///
    /// Why: a tool that moves occluders (`calibrate occluder`) writes them
    /// in the file's own terms, and a relative mesh path must be rewritten
    /// for a file written to another folder.
    pub fn occluder_tables(
        &self,
        path: &mut dyn FnMut(usize, &str) -> Result<String, SceneError>,
    ) -> Result<Vec<toml::Table>, SceneError> {
        let mut out = Vec::with_capacity(self.occluders().len());
        for (i, o) in self.occluders().iter().enumerate() {
            let mut raw = raw_occluder(o.clone());
            if let Some(p) = raw.mesh.take() {
                raw.mesh = Some(path(i, &p)?);
            }
            let table = toml::Table::try_from(&raw).map_err(|e| {
                SceneError::invalid(
                    format!("occluder[{i}]"),
                    o,
                    format!("cannot be written: {e}"),
                )
            })?;
            out.push(table);
        }
        Ok(out)
    }
}
