//! Validating a parsed scene file into a [`Scene`]: every key checked
//! against its range, each error naming the key and what to do.

use super::*;

pub(super) fn point(key: &str, v: [f64; 3]) -> Result<Vec3, SceneError> {
    if v.iter().any(|x| !x.is_finite()) {
        return Err(SceneError::invalid(key, v, "must be three finite numbers"));
    }
    Ok(Vec3::from(v))
}

pub(super) fn direction(key: &str, v: [f64; 3]) -> Result<Vec3, SceneError> {
    let p = point(key, v)?;
    let n = p.norm();
    if n < 1e-12 {
        return Err(SceneError::invalid(key, v, "must be a non-zero direction"));
    }
    Ok(p / n)
}

pub(super) fn plane(
    section: &str,
    c: [f64; 3],
    n: [f64; 3],
    u: [f64; 3],
    size: [f64; 2],
    grid: [i64; 2],
    m: i64,
) -> Result<Plane, SceneError> {
    let center = point(&format!("{section}.center"), c)?;
    let normal = direction(&format!("{section}.normal"), n)?;
    let u_raw = direction(&format!("{section}.u_axis"), u)?;
    // Gram-Schmidt: keep u in the plane even when the file is slightly off.
    let u_perp = u_raw - normal * normal.dot(&u_raw);
    if u_perp.norm() < 1e-6 {
        return Err(SceneError::invalid(
            format!("{section}.u_axis"),
            u,
            format!("is parallel to {section}.normal; it must lie in the plane"),
        ));
    }
    let u_axis = u_perp.normalize();
    if size.iter().any(|s| !s.is_finite() || *s <= 0.0) {
        return Err(SceneError::invalid(
            format!("{section}.size"),
            size,
            "both sides must be positive metres",
        ));
    }
    if grid.iter().any(|g| *g < 1 || *g > MAX_GRID) {
        return Err(SceneError::invalid(
            format!("{section}.grid"),
            grid,
            format!("both counts must be whole numbers from 1 to {MAX_GRID}"),
        ));
    }
    if !(1..=MAX_SUPERSAMPLE).contains(&m) {
        return Err(SceneError::invalid(
            format!("{section}.supersample"),
            m,
            format!("must be a whole number from 1 to {MAX_SUPERSAMPLE}"),
        ));
    }
    Ok(Plane {
        center,
        normal,
        u: u_axis,
        v: normal.cross(&u_axis),
        size,
        grid: Grid {
            nu: grid[0] as usize,
            nv: grid[1] as usize,
        },
        supersample: m as usize,
    })
}

/// A `mesh` occluder: the OBJ or STL file at `path` (relative to `dir`, the
/// scene file's folder), its vertices times `scale` plus `offset`; whatever
/// is wrong with the keys or the file is an error naming `occluder[i].mesh`
/// (or `.scale`, `.offset`).
pub(super) fn mesh_occluder(
    key: &dyn Fn(&str) -> String,
    dir: &Path,
    path: String,
    scale: Option<f64>,
    offset: Option<[f64; 3]>,
) -> Result<Mesh, SceneError> {
    let factor = scale.unwrap_or(1.0);
    if !(factor.is_finite() && factor > 0.0) {
        return Err(SceneError::invalid(
            key("scale"),
            factor,
            "must be a finite number > 0 (metres per mesh unit, e.g. 0.001 for millimetres)",
        ));
    }
    let shift = point(&key("offset"), offset.unwrap_or([0.0; 3]))?;
    if path.trim().is_empty() {
        return Err(SceneError::invalid(
            key("mesh"),
            &path,
            "must name an .obj or .stl file",
        ));
    }
    let bad = |e: MeshError| SceneError::invalid(key("mesh"), &path, e.to_string());
    let raw = mesh::read(&dir.join(&path)).map_err(bad)?;
    let triangles = mesh::place(&raw, factor, shift).map_err(bad)?;
    Ok(Mesh::new(
        triangles,
        MeshSource {
            path,
            scale,
            offset,
        },
    ))
}

/// Largest refractive index accepted for the wall (germanium, the highest
/// common optical material, is about 4).
pub(super) const MAX_IOR: f64 = 5.0;

/// Largest camera frame side accepted in a pose's region, pixels.
pub(super) const MAX_FRAME_SIDE: i64 = 65_536;

/// Whether two linear-polarizer angles (degrees) are the same setting: equal modulo 180.
pub(super) fn same_polarizer_setting(a: f64, b: f64) -> bool {
    let d = (a - b).rem_euclid(180.0);
    d < 1e-6 || 180.0 - d < 1e-6
}

/// A pose's on-chip polarizer mosaic (MODEL.md "On-chip polarizer mosaic"):
/// `analyzer = "mosaic"` with `sensor_deg`, `extinction` and `layout`; the
/// last three without it, or a mosaic with `polarizer_deg`, are errors naming the keys.
pub(super) fn mosaic(
    key: &dyn Fn(&str) -> String,
    p: &RawPose,
) -> Result<Option<Mosaic>, SceneError> {
    match p.analyzer.as_deref() {
        None => {
            for (k, given) in [
                ("sensor_deg", p.sensor_deg.is_some()),
                ("extinction", p.extinction.is_some()),
                ("layout", p.layout.is_some()),
            ] {
                if given {
                    return Err(SceneError::invalid(
                        key(k),
                        &p.name,
                        "belongs to a pose with analyzer = \"mosaic\"; add that key or remove this one",
                    ));
                }
            }
            Ok(None)
        }
        Some("mosaic") => {
            if let Some(deg) = &p.polarizer_deg {
                return Err(SceneError::invalid(
                    format!("{} and {}", key("analyzer"), key("polarizer_deg")),
                    deg,
                    "a pose has either a polarizer sheet (polarizer_deg) or an on-chip mosaic (analyzer = \"mosaic\"), not both; remove one",
                ));
            }
            let sensor_deg = p.sensor_deg.unwrap_or(0.0);
            if !(-360.0..=360.0).contains(&sensor_deg) {
                return Err(SceneError::invalid(
                    key("sensor_deg"),
                    sensor_deg,
                    "must be degrees from -360 to 360",
                ));
            }
            if let Some(e) = p.extinction {
                if !(e > 1.0 && e.is_finite()) {
                    return Err(SceneError::invalid(
                        key("extinction"),
                        e,
                        "must be a finite ratio above 1 (e.g. 300); leave it out for ideal micro-polarizers",
                    ));
                }
            }
            let layout = match p.layout.as_deref() {
                None => MosaicLayout::default(),
                Some(name) => MosaicLayout::from_name(name).ok_or_else(|| {
                    SceneError::invalid(
                        key("layout"),
                        name,
                        format!(
                            "is not a known mosaic layout; known: {}",
                            MosaicLayout::ALL.map(MosaicLayout::name).join(", ")
                        ),
                    )
                })?,
            };
            Ok(Some(Mosaic {
                sensor_deg,
                extinction: p.extinction,
                layout,
            }))
        }
        Some(other) => Err(SceneError::invalid(
            key("analyzer"),
            other,
            "must be \"mosaic\" (an on-chip polarizer mosaic); leave it out for a polarizer sheet (polarizer_deg) or none",
        )),
    }
}

/// The camera frame a pose's homography was calibrated at: `region` (and
/// `binning`, default 1 x 1); both absent means the pose does not say.
pub(super) fn camera_frame(
    key: &dyn Fn(&str) -> String,
    region: Option<[i64; 4]>,
    binning: Option<[i64; 2]>,
) -> Result<Option<CameraFrame>, SceneError> {
    let Some(r) = region else {
        if binning.is_some() {
            return Err(SceneError::invalid(
                key("binning"),
                binning,
                "needs region = [x, y, width, height] too: the frame the homography was calibrated at",
            ));
        }
        return Ok(None);
    };
    let [x, y, w, h] = r;
    if x < 0
        || y < 0
        || !(1..=MAX_FRAME_SIDE).contains(&w)
        || !(1..=MAX_FRAME_SIDE).contains(&h)
        || x + w > MAX_FRAME_SIDE
        || y + h > MAX_FRAME_SIDE
    {
        return Err(SceneError::invalid(
            key("region"),
            r,
            format!("must be [x, y, width, height] in pixels: offsets >= 0, sizes from 1 and everything within {MAX_FRAME_SIDE}"),
        ));
    }
    let b = binning.unwrap_or([1, 1]);
    if !b.iter().all(|v| (1..=64).contains(v)) {
        return Err(SceneError::invalid(
            key("binning"),
            b,
            "must be [x, y] factors from 1 to 64",
        ));
    }
    // The bounds above make every value fit u32.
    let u = |v: i64| v as u32;
    Ok(Some(CameraFrame {
        region: [u(x), u(y), u(w), u(h)],
        binning: [u(b[0]), u(b[1])],
    }))
}

/// `[wall] diffuse`: `"fresnel"` (default) or `"lambert"`.
pub(super) fn diffuse_model(v: Option<toml::Value>) -> Result<DiffuseModel, SceneError> {
    let Some(v) = v else {
        return Ok(DiffuseModel::default());
    };
    v.as_str()
        .and_then(DiffuseModel::from_name)
        .ok_or_else(|| {
            SceneError::invalid(
                "wall.diffuse",
                v.to_string(),
                "must be \"fresnel\" (both interfaces of the wall, the default) or \"lambert\" (ideal depolarized Lambertian)",
            )
        })
}

/// `[wall] sampling`: `"uniform"` (default) or `"pixels"`.
pub(super) fn wall_sampling(v: Option<toml::Value>) -> Result<WallSampling, SceneError> {
    let Some(v) = v else {
        return Ok(WallSampling::default());
    };
    v.as_str().and_then(WallSampling::from_name).ok_or_else(|| {
        SceneError::invalid(
            "wall.sampling",
            v.to_string(),
            "must be \"uniform\" (the element's supersample points, the default) or \"pixels\" (the wall points of the element's pixels, as the measurement weighs them)",
        )
    })
}

/// `[polarizer]`: only `model = "absorbing"` (default) or `"transmitting"`.
pub(super) fn polarizer_model(t: Option<toml::Table>) -> Result<PolarizerModel, SceneError> {
    let Some(t) = t else {
        return Ok(PolarizerModel::default());
    };
    if let Some((key, v)) = t.iter().find(|(k, _)| k.as_str() != "model") {
        return Err(SceneError::invalid(
            format!("polarizer.{key}"),
            v.to_string(),
            "is not a key of [polarizer]; it takes only model = \"absorbing\" or \"transmitting\"",
        ));
    }
    let Some(v) = t.get("model") else {
        return Ok(PolarizerModel::default());
    };
    v.as_str()
        .and_then(PolarizerModel::from_name)
        .ok_or_else(|| {
            SceneError::invalid(
                "polarizer.model",
                v.to_string(),
                "must be \"absorbing\" (the tilted sheet as measured, the default) or \"transmitting\"",
            )
        })
}

pub(super) fn validate(raw: RawFile, dir: &Path) -> Result<Scene, SceneError> {
    let polarizer = polarizer_model(raw.polarizer)?;
    let left_out = LeftOut {
        wall_supersample: raw.wall.supersample.is_none(),
        scene_supersample: raw.scene.supersample.is_none(),
        sampling: raw.wall.sampling.is_none(),
    };
    let wall = validate_wall(raw.wall)?;
    let hidden = validate_hidden(raw.scene, &wall.plane)?;
    let poses = validate_poses(raw.pose, &wall.plane, &hidden.plane)?;
    let occluders = validate_occluders(raw.occluder, dir)?;
    check_pixel_sampling(wall.sampling, &poses)?;
    Ok(Scene {
        wall,
        hidden,
        poses,
        occluders,
        polarizer,
        left_out,
    })
}

/// `[wall]`: its plane, its BRDF (roughness, index, weights, diffuse model) and its sampling.
/// The first section checked, so its errors come before any of `[scene]`'s, as they always have.
pub(super) fn validate_wall(w: RawWall) -> Result<Wall, SceneError> {
    let sampling = wall_sampling(w.sampling)?;
    let wall_plane = plane(
        "wall",
        w.center,
        w.normal,
        w.u_axis,
        w.size,
        w.grid,
        w.supersample.unwrap_or(1),
    )?;
    if !(w.roughness > 0.0 && w.roughness <= 1.0) {
        return Err(SceneError::invalid(
            "wall.roughness",
            w.roughness,
            "must be in (0, 1]",
        ));
    }
    if !(w.ior > 1.0 && w.ior <= MAX_IOR) {
        return Err(SceneError::invalid(
            "wall.ior",
            w.ior,
            format!("must be a refractive index in (1, {MAX_IOR}] (paint and plaster about 1.5)"),
        ));
    }
    for (key, k) in [("wall.ks", w.ks), ("wall.kd", w.kd)] {
        if !(k >= 0.0 && k.is_finite()) {
            return Err(SceneError::invalid(key, k, "must be a finite weight >= 0"));
        }
    }
    let brdf = Brdf {
        alpha: w.roughness,
        eta: w.ior,
        ks: w.ks,
        kd: w.kd,
        diffuse: diffuse_model(w.diffuse)?,
    };
    Ok(Wall {
        plane: wall_plane,
        brdf,
        sampling,
    })
}

/// `[scene]`: the emitting plane, which must be in front of `wall`, with its lobe and polarization.
/// The side checks need the wall's plane, so this runs after [`validate_wall`].
pub(super) fn validate_hidden(s: RawScenePlane, wall: &Plane) -> Result<HiddenScene, SceneError> {
    let scene_plane = plane(
        "scene",
        s.center,
        s.normal,
        s.u_axis,
        s.size,
        s.grid,
        s.supersample.unwrap_or(1),
    )?;
    let n = wall.normal;
    let c0 = wall.center;
    let s0 = scene_plane.center;
    if n.dot(&(s0 - c0)) <= 0.0 {
        return Err(SceneError::invalid(
            "scene.center",
            s.center,
            "is on or behind the wall; it must be on the side wall.normal points to",
        ));
    }
    if s.emitter == Emitter::Lambertian && scene_plane.normal.dot(&(c0 - s0)) <= 0.0 {
        return Err(SceneError::invalid(
            "scene.normal",
            s.normal,
            "faces away from the wall centre; a lambertian screen must face the wall (flip its sign or use emitter = \"isotropic\")",
        ));
    }
    let polarization = s
        .polarization
        .map(|p| direction("scene.polarization", p))
        .transpose()?;
    if let Some(l) = s.lobe {
        if !l
            .iter()
            .all(|n| n.is_finite() && (0.0..=MAX_LOBE).contains(n))
        {
            return Err(SceneError::invalid(
                "scene.lobe",
                l,
                "must be two exponents [n_u, n_v], each from 0 to 1000 (a monitor: about [1, 18])",
            ));
        }
    }
    let lobe = s.lobe.filter(|l| l.iter().any(|n| *n != 0.0));
    Ok(HiddenScene {
        plane: scene_plane,
        emitter: s.emitter,
        lobe,
        polarization,
        shadows: s.shadows.unwrap_or_default(),
    })
}

/// `[[pose]]`: at least one, each checked in file order against the earlier ones.
/// Names must be unique, so each pose is validated knowing the poses before it.
pub(super) fn validate_poses(
    raw: Vec<RawPose>,
    wall: &Plane,
    scene: &Plane,
) -> Result<Vec<Pose>, SceneError> {
    if raw.is_empty() {
        return Err(SceneError::invalid(
            "pose",
            "[]",
            "at least one [[pose]] is required",
        ));
    }
    let mut poses = Vec::with_capacity(raw.len());
    for (i, p) in raw.into_iter().enumerate() {
        let pose = validate_pose(i, p, &poses, wall, scene)?;
        poses.push(pose);
    }
    Ok(poses)
}

/// `pose[i]`: its name, camera (in front of the wall), analyzers, homography and frame.
/// One pose's keys together, so every error names `pose[i].key` as before.
pub(super) fn validate_pose(
    i: usize,
    p: RawPose,
    earlier: &[Pose],
    wall: &Plane,
    scene: &Plane,
) -> Result<Pose, SceneError> {
    let key = |k: &str| format!("pose[{i}].{k}");
    let name = pose_name(&key, &p.name, earlier)?;
    let camera = point(&key("camera"), p.camera)?;
    if wall.normal.dot(&(camera - wall.center)) <= 0.0 {
        return Err(SceneError::invalid(
            key("camera"),
            p.camera,
            format!("pose {name:?}: the camera is on or behind the wall"),
        ));
    }
    let mosaic = mosaic(&key, &p)?;
    let analyzers = pose_analyzers(
        &key,
        &p,
        &name,
        mosaic.as_ref(),
        &wall.center,
        &scene.center,
        &camera,
    )?;
    let homography = match p.homography {
        None => None,
        Some(h) => Some(Homography::new(h).ok_or_else(|| {
            SceneError::invalid(
                key("homography"),
                h,
                "must be a finite, invertible 3x3 matrix",
            )
        })?),
    };
    let frame = camera_frame(&key, p.region, p.binning)?;
    if let (Some(_), Some(f)) = (&mosaic, &frame) {
        if f.binning != [1, 1] {
            return Err(SceneError::invalid(
                key("binning"),
                f.binning,
                "must be [1, 1] on a pose with analyzer = \"mosaic\": a binned pixel mixes the micro-polarizers of a 2x2 cell",
            ));
        }
    }
    Ok(Pose {
        name,
        camera,
        analyzers,
        mosaic,
        homography,
        frame,
    })
}

/// A pose's name, trimmed: 1-64 letters, digits, '-', '_' or '.', unused by `earlier`.
/// Captures and API requests name poses, so a name must be safe and unambiguous.
pub(super) fn pose_name(
    key: &dyn Fn(&str) -> String,
    raw: &str,
    earlier: &[Pose],
) -> Result<String, SceneError> {
    let name = raw.trim().to_string();
    if name.is_empty()
        || name.len() > 64
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
    {
        return Err(SceneError::invalid(
            key("name"),
            raw,
            "must be 1-64 letters, digits, '-', '_' or '.'",
        ));
    }
    if earlier.iter().any(|q| q.name == name) {
        return Err(SceneError::invalid(
            key("name"),
            &name,
            "is used by an earlier pose; names must be unique",
        ));
    }
    Ok(name)
}

/// A pose's analyzers in block order: the mosaic's micro-polarizers, then the sheet's angles.
/// Both need the crossed axis of camera `o`, wall centre `c0` and scene centre `s0`, checked first.
pub(super) fn pose_analyzers(
    key: &dyn Fn(&str) -> String,
    p: &RawPose,
    name: &str,
    mosaic: Option<&Mosaic>,
    c0: &Vec3,
    s0: &Vec3,
    camera: &Vec3,
) -> Result<Vec<Analyzer>, SceneError> {
    let polarizer_deg = p.polarizer_deg.clone().unwrap_or_default();
    let mut analyzers = Vec::with_capacity(polarizer_deg.len());
    if (!polarizer_deg.is_empty() || mosaic.is_some()) && crossed_axis(c0, s0, camera).is_none() {
        let k = if mosaic.is_some() {
            "analyzer"
        } else {
            "polarizer_deg"
        };
        return Err(SceneError::invalid(
            key(k),
            &p.polarizer_deg,
            format!("pose {name:?}: the crossed axis is undefined because the camera, the wall centre and the scene centre are collinear"),
        ));
    }
    if let Some(m) = mosaic {
        // The crossed axis exists (checked above), so every angle has a micro-polarizer.
        analyzers.extend(Analyzer::mosaic(c0, s0, camera, m).into_iter().flatten());
    }
    for (k, &deg) in polarizer_deg.iter().enumerate() {
        if !(-360.0..=360.0).contains(&deg) {
            return Err(SceneError::invalid(
                key("polarizer_deg"),
                &polarizer_deg,
                "angles must be degrees from -360 to 360",
            ));
        }
        // A linear polarizer at a and at a + 180 degrees is the same setting.
        if let Some(&earlier) = polarizer_deg[..k]
            .iter()
            .find(|&&e| same_polarizer_setting(e, deg))
        {
            return Err(SceneError::invalid(
                key("polarizer_deg"),
                &polarizer_deg,
                format!("{deg} and {earlier} degrees are the same polarizer setting (angles repeat every 180 degrees); list each setting once"),
            ));
        }
        // The crossed axis exists (checked above), so every angle has a sheet.
        if let Some(a) = Analyzer::at(c0, s0, camera, deg) {
            analyzers.push(a);
        }
    }
    Ok(analyzers)
}

/// `[[occluder]]`: each checked in file order, meshes read from `dir` unless already loaded.
/// Kept apart from the poses: occluders need nothing from the other sections.
pub(super) fn validate_occluders(
    raw: Vec<RawOccluder>,
    dir: &Path,
) -> Result<Vec<Occluder>, SceneError> {
    let mut occluders = Vec::with_capacity(raw.len());
    for (i, o) in raw.into_iter().enumerate() {
        occluders.push(validate_occluder(i, o, dir)?);
    }
    Ok(occluders)
}

/// `occluder[i]`: exactly one of a rect, a sphere or a mesh (with its `scale` and `offset`).
/// One occluder's keys together, so every error names `occluder[i].key` as before.
pub(super) fn validate_occluder(
    i: usize,
    o: RawOccluder,
    dir: &Path,
) -> Result<Occluder, SceneError> {
    let key = |k: &str| format!("occluder[{i}].{k}");
    if o.mesh.is_none() {
        let only = "belongs to a mesh occluder (mesh = \"file.obj\"); remove it or add mesh";
        if let Some(v) = o.scale {
            return Err(SceneError::invalid(key("scale"), v, only));
        }
        if let Some(v) = o.offset {
            return Err(SceneError::invalid(key("offset"), v, only));
        }
    }
    match (o.rect, o.sphere, o.mesh) {
        (None, None, Some(path)) => {
            let mesh = match o.loaded {
                Some(mesh) => mesh,
                None => Arc::new(mesh_occluder(&key, dir, path, o.scale, o.offset)?),
            };
            Ok(Occluder::Mesh(mesh))
        }
        (Some(r), None, None) => rect_occluder(&key, r),
        (None, Some(sp), None) => {
            let center = point(&key("sphere.center"), sp.center)?;
            if !(sp.radius > 0.0 && sp.radius.is_finite()) {
                return Err(SceneError::invalid(
                    key("sphere.radius"),
                    sp.radius,
                    "must be positive metres",
                ));
            }
            Ok(Occluder::Sphere {
                center,
                radius: sp.radius,
            })
        }
        _ => Err(SceneError::invalid(
            key(""),
            "",
            "give exactly one of rect = {...}, sphere = {...} or mesh = \"file.obj\"",
        )),
    }
}

/// A `rect` occluder: finite centre and half-axes, non-zero and not parallel.
/// Parallel or zero half-axes span no area, so the rectangle would cast no shadow.
pub(super) fn rect_occluder(
    key: &dyn Fn(&str) -> String,
    r: RawRect,
) -> Result<Occluder, SceneError> {
    let center = point(&key("rect.center"), r.center)?;
    let half_u = point(&key("rect.half_u"), r.half_u)?;
    let half_v = point(&key("rect.half_v"), r.half_v)?;
    if half_u.cross(&half_v).norm() <= 1e-12 * half_u.norm().max(1e-300) * half_v.norm().max(1e-300)
        || half_u.norm() == 0.0
        || half_v.norm() == 0.0
    {
        return Err(SceneError::invalid(
            key("rect"),
            (r.half_u, r.half_v),
            "half_u and half_v must be non-zero and not parallel",
        ));
    }
    Ok(Occluder::Rect {
        center,
        half_u,
        half_v,
    })
}

/// `sampling = "pixels"` needs every pose's homography.
/// Rows over an element's pixels map the wall to the image through it (MODEL.md "Rows that match the measurement").
pub(super) fn check_pixel_sampling(
    sampling: WallSampling,
    poses: &[Pose],
) -> Result<(), SceneError> {
    if sampling == WallSampling::Pixels {
        if let Some(i) = poses.iter().position(|p| p.homography.is_none()) {
            return Err(SceneError::invalid(
                format!("pose[{i}].homography"),
                "absent",
                "is required by wall.sampling = \"pixels\" (rows over the element's pixels need the pose's homography); add it, or use sampling = \"uniform\"",
            ));
        }
    }
    Ok(())
}
