//! Where each pose's camera sees a scene's wall (`GET /scenes/{name}/wall`),
//! for aiming the live view at it.

use crate::scene::Scene;

/// Where a pose's camera sees a scene's wall, for aiming the live view at it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct WallView {
    /// Pose name.
    pub pose: String,
    /// The wall's corners (-u, -v), (+u, -v), (+u, +v), (-u, +v) in unbinned
    /// sensor pixels through the pose's homography; null when the pose has
    /// none (or its wall is not wholly in view), with `why`.
    pub corners: Option<[[f64; 2]; 4]>,
    /// The wall's centre (u, v) = (0, 0), sensor pixels; null likewise.
    pub centre: Option<[f64; 2]>,
    /// Why there are no corners.
    pub why: Option<String>,
}

/// The wall as each pose of `scene` sees it, in file order.
pub(crate) fn wall_views(scene: &Scene) -> Vec<WallView> {
    let wall = &scene.wall().plane;
    scene
        .poses()
        .iter()
        .map(|p| {
            let seen = match &p.homography {
                None => Err(format!(
                    "pose {:?} has no homography: capture the dot target at this pose (\"kind\": \"target\") and fit its homography with POST /calibrations, then load the scene file it returns",
                    p.name
                )),
                Some(h) => crate::scene::wall_corners(h, wall, &p.name)
                    .map_err(|e| e.to_string())
                    .and_then(|corners| {
                        let (x, y) = h.apply(0.0, 0.0).ok_or_else(|| {
                            format!("pose {:?}: the wall's centre maps to infinity", p.name)
                        })?;
                        Ok((corners, [x, y]))
                    }),
            };
            match seen {
                Ok((corners, centre)) => WallView {
                    pose: p.name.clone(),
                    corners: Some(corners),
                    centre: Some(centre),
                    why: None,
                },
                Err(why) => WallView {
                    pose: p.name.clone(),
                    corners: None,
                    centre: None,
                    why: Some(why),
                },
            }
        })
        .collect()
}
