//! `GET /openapi.json`, generated from the handlers' annotations (utoipa):
//! the router declares each route once (see `super::all_routes`) and its
//! paths come from there; this module adds what every route shares.

use std::sync::Arc;

use axum::Json;
use utoipa::openapi::OpenApi as Document;
use utoipa::{Modify, OpenApi};

use super::routes;
use crate::daemon::Daemon;

/// The document before the router adds its paths: title, description, and
/// the schemas listed here. Operations add those they name (every request
/// body among them), so a new route lists nothing here.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "polnlos",
        description = "Polarization-enhanced passive NLOS imaging: captures, reconstructions, camera."
    ),
    components(schemas(
        crate::solve::SolveRequest,
        super::bodies::Health,
        routes::Deleted,
        super::bodies::Accepted,
        super::bodies::CaptureAccepted,
        super::bodies::ErrorBody,
        super::bodies::ProgressiveBody,
        crate::daemon::GeometryCalibration,
        super::bodies::SourcePositionBody,
        crate::daemon::WallCalibration,
        crate::daemon::FittedPosition,
        crate::daemon::ProgressiveStep,
        crate::camera::CameraSettings,
        crate::camera::Acquisition,
        crate::store::CaptureRecord,
        crate::store::ReconstructionRecord,
        crate::store::JobState,
        crate::store::CaptureKind,
        crate::daemon::CameraView,
        crate::daemon::DemoView,
        crate::rig::mount::MountView,
        super::bodies::PlanReconstruct,
        crate::daemon::PlanView,
        crate::daemon::PlanStep,
        crate::store::PlanRow,
        crate::store::PlanState,
        crate::store::PlanCapture,
        crate::store::PlanInterim,
        crate::rig::mount::MountKind,
        crate::rig::stage::StageView,
        crate::rig::stage::StageKind,
        crate::rig::relay::LightView,
        crate::rig::relay::LightKind,
        crate::daemon::ZeroFit,
        crate::daemon::SweepPoint,
        crate::daemon::ZeroLight,
        crate::camera::worker::CameraStatus,
        crate::camera::CameraInfo,
        crate::camera::CameraRanges,
        crate::camera::Counters,
        crate::camera::SensorLimits,
        crate::camera::PixelFormat,
        crate::camera::TriggerMode,
        crate::measure::exposure::ExposureTarget,
        crate::measure::exposure::BlockExposure,
        crate::daemon::runtime::scenes::WallView,
        crate::daemon::runtime::scenes::SceneListing,
        crate::daemon::runtime::scenes::SceneOrigin,
    ))
)]
struct Doc;

/// Who may call what, as the guard enforces it: the bearer token on every
/// route but `/health` (and the page's files, this document among them),
/// reads open to all with `[http] public_reads`, and nothing at all when
/// the daemon has no token.
#[derive(Debug, Clone, Copy)]
pub struct Access {
    /// The daemon has a token.
    pub token: bool,
    /// `GET` routes need no token.
    pub public_reads: bool,
}

impl Access {
    /// Writes the bearer scheme and each operation's requirement into `doc`.
    fn apply(self, doc: &mut Document) {
        use utoipa::openapi::security::{
            HttpAuthScheme, HttpBuilder, SecurityRequirement, SecurityScheme,
        };
        let components = doc.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some(
                        "The token of [http] token_file; not needed when the daemon has none",
                    ))
                    .build(),
            ),
        );
        let bearer = || vec![SecurityRequirement::new("bearer", Vec::<String>::new())];
        doc.security = Some(if self.token { bearer() } else { Vec::new() });
        for (path, item) in doc.paths.paths.iter_mut() {
            let public_path = path == "/health";
            let ops = [
                (&mut item.get, true),
                (&mut item.put, false),
                (&mut item.post, false),
                (&mut item.delete, false),
            ];
            for (op, read) in ops {
                let Some(op) = op.as_mut() else { continue };
                let public = !self.token || public_path || (read && self.public_reads);
                op.security = Some(if public { Vec::new() } else { bearer() });
            }
        }
    }
}

/// Errors every route can answer (the guard's and the extractors'), and the
/// JSON body of every error response.
struct Errors;

impl Modify for Errors {
    fn modify(&self, doc: &mut Document) {
        use utoipa::openapi::{ContentBuilder, Ref, ResponseBuilder};
        let error = || {
            ContentBuilder::new()
                .schema(Some(Ref::from_schema_name("ErrorBody")))
                .build()
        };
        let common = [
            ("400", "A query string, path or body that cannot be read"),
            (
                "422",
                "A value out of range or of the wrong type (the detail names it)",
            ),
            ("401", "The bearer token is missing or wrong"),
            ("403", "A foreign Host or Origin header"),
            ("414", "The request target is over 8 KiB"),
            ("431", "Over 64 header lines or 16 KiB of headers"),
            ("500", "The daemon failed (the detail says where)"),
        ];
        for op in operations(doc) {
            for (code, what) in common {
                op.responses
                    .responses
                    .entry(code.to_string())
                    .or_insert_with(|| {
                        ResponseBuilder::new()
                            .description(what)
                            .content("application/json", error())
                            .build()
                            .into()
                    });
            }
            if op.request_body.is_some() {
                op.responses
                    .responses
                    .entry("415".to_string())
                    .or_insert_with(|| {
                        ResponseBuilder::new()
                            .description("A body that is not Content-Type: application/json")
                            .content("application/json", error())
                            .build()
                            .into()
                    });
            }
            for (code, r) in op.responses.responses.iter_mut() {
                if code.as_str() >= "400" {
                    if let utoipa::openapi::RefOr::T(r) = r {
                        r.content
                            .entry("application/json".into())
                            .or_insert_with(error);
                    }
                }
            }
        }
    }
}

/// The OpenAPI document of this daemon: `doc`, the routes' document
/// ([`finish`]ed), with the token its configuration asks for where it asks
/// for one, and the scene and pose names it knows (so a generated request
/// can reach past their 422).
pub async fn spec(d: Arc<Daemon>, doc: Arc<Document>) -> Json<serde_json::Value> {
    let doc = document(
        &doc,
        Access {
            token: !d.token().is_empty(),
            public_reads: d.config().http.public_reads,
        },
    );
    Json(with_names(
        serde_json::to_value(doc).unwrap_or_default(),
        &d.scenes().names(),
        &d.scenes().pose_names(),
    ))
}

/// `doc` with `scenes` as the enum of every scene name it takes (bodies and
/// the exposure route's path) and `poses` as the enum of a capture's pose.
pub fn with_names(
    mut doc: serde_json::Value,
    scenes: &[String],
    poses: &[String],
) -> serde_json::Value {
    let mut scenes = scenes.to_vec();
    scenes.sort();
    let schemas = &mut doc["components"]["schemas"];
    for body in ["CaptureBody", "ReconstructionBody", "WallCalibrationBody"] {
        if let Some(scene) = property(&mut schemas[body], "scene") {
            scene["enum"] = serde_json::json!(scenes);
        }
    }
    if let Some(pose) = property(&mut schemas["CaptureBody"], "pose") {
        pose["enum"] = serde_json::json!(poses);
    }
    if let Some(params) =
        doc["paths"]["/scenes/{name}/exposure"]["get"]["parameters"].as_array_mut()
    {
        for p in params.iter_mut().filter(|p| p["name"] == "name") {
            p["schema"]["enum"] = serde_json::json!(scenes);
        }
    }
    doc
}

/// The schema of property `name` of an object schema, also where a body
/// embeds another struct's fields (`allOf` of the two).
fn property<'a>(
    schema: &'a mut serde_json::Value,
    name: &str,
) -> Option<&'a mut serde_json::Value> {
    if schema["properties"][name].is_object() {
        return schema["properties"].get_mut(name);
    }
    schema["allOf"]
        .as_array_mut()?
        .iter_mut()
        .find(|part| part["properties"][name].is_object())?["properties"]
        .get_mut(name)
}

/// Every operation of the document (the methods the API serves).
fn operations(doc: &mut Document) -> impl Iterator<Item = &mut utoipa::openapi::path::Operation> {
    doc.paths.paths.values_mut().flat_map(|item| {
        [
            &mut item.get,
            &mut item.put,
            &mut item.post,
            &mut item.delete,
        ]
        .into_iter()
        .flatten()
    })
}

/// The base the router adds its paths to: title, description, schemas.
pub fn base() -> Document {
    Doc::openapi()
}

/// The router's document made whole: the errors every route can answer on
/// each operation, and each operation's tag `routes` (the handlers' module,
/// which the document has always named; clients grouping by tag see the
/// same group).
pub fn finish(mut doc: Document) -> Document {
    Errors.modify(&mut doc);
    for op in operations(&mut doc) {
        op.tags.get_or_insert_with(|| vec!["routes".into()]);
    }
    doc
}

/// `doc` for a given access policy.
pub fn document(doc: &Document, access: Access) -> Document {
    let mut doc = doc.clone();
    access.apply(&mut doc);
    doc
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The routes' document for `access`, as `/openapi.json` builds it.
    fn routes_document(access: Access) -> Document {
        document(
            &finish(super::super::all_routes(1 << 20).into_openapi()),
            access,
        )
    }

    fn security(doc: &Document, path: &str, method: &str) -> serde_json::Value {
        let v = serde_json::to_value(doc).unwrap_or_default();
        v["paths"][path][method]["security"].clone()
    }

    #[test]
    fn the_document_says_which_routes_need_the_token() {
        let bearer = serde_json::json!([{ "bearer": [] }]);
        let none = serde_json::json!([]);
        let doc = routes_document(Access {
            token: true,
            public_reads: false,
        });
        assert_eq!(security(&doc, "/health", "get"), none);
        assert_eq!(security(&doc, "/captures", "get"), bearer);
        assert_eq!(security(&doc, "/captures", "post"), bearer);
        let doc = routes_document(Access {
            token: true,
            public_reads: true,
        });
        assert_eq!(security(&doc, "/captures", "get"), none);
        assert_eq!(security(&doc, "/jobs/{id}", "delete"), bearer);
        let doc = routes_document(Access {
            token: false,
            public_reads: false,
        });
        assert_eq!(security(&doc, "/captures", "post"), none);
        let v = serde_json::to_value(&doc).unwrap_or_default();
        assert_eq!(v["security"], none);
        // 415 where a body is read, 422 everywhere.
        let post = &v["paths"]["/captures"]["post"]["responses"];
        assert!(post["415"].is_object() && post["422"].is_object(), "{post}");
        assert!(v["paths"]["/captures"]["get"]["responses"]["422"].is_object());
        assert!(v["paths"]["/captures"]["get"]["responses"]["415"].is_null());
        // Scene and pose names appear as enums.
        let mut v = with_names(v, &["b".into(), "a".into()], &["A".into()]);
        let body = &mut v["components"]["schemas"]["CaptureBody"];
        let scene = property(body, "scene").cloned().unwrap_or_default();
        assert_eq!(scene["enum"], serde_json::json!(["a", "b"]), "{scene}");
        let pose = property(body, "pose").cloned().unwrap_or_default();
        assert_eq!(pose["enum"], serde_json::json!(["A"]), "{pose}");
        // The camera settings a capture body embeds are documented in it.
        let exposure = property(body, "exposure_us").cloned();
        assert!(exposure.is_none(), "embedded by reference, not copied");
        assert_eq!(
            body["allOf"][0]["$ref"], "#/components/schemas/CameraSettings",
            "{body}"
        );
        let name = &v["paths"]["/scenes/{name}/exposure"]["get"]["parameters"][0];
        assert_eq!(
            name["schema"]["enum"],
            serde_json::json!(["a", "b"]),
            "{name}"
        );
        // kappa: a number, "inf" or null, not an object.
        let kappa = &v["components"]["schemas"]["ReconstructionRecord"]["properties"]["kappa"];
        assert_eq!(kappa["oneOf"][0]["type"], "number", "{kappa}");
        assert_eq!(
            kappa["oneOf"][1]["enum"],
            serde_json::json!(["inf"]),
            "{kappa}"
        );
    }
}
