//! Plans: run a scene block by block, list them, cancel or continue one.

use super::*;

/// Queues an acquisition plan: every block of the scene, then its
/// reconstruction; operator steps wait for `POST /plans/{id}/continue`.
#[utoipa::path(post, path = "/plans", request_body = PlanBody, responses((status = 202, body = crate::daemon::PlanView, description = "Queued; Location names the plan; the body lists its steps"), (status = 404, description = "Unknown scene"), (status = 422, description = "A capture of the plan would be refused")))]
pub async fn post_plan(State(d): St, ApiJson(b): ApiJson<PlanBody>) -> Result<Response, ApiError> {
    let view = d.plans().submit_plan(b).await?;
    Ok(accepted("plan", view.plan.id, view))
}

/// Plans, newest first.
#[utoipa::path(get, path = "/plans", params(Page), responses((status = 200, body = [crate::store::PlanRow], headers(("polnlos-unreadable" = String, description = "Ids of this page's rows the catalogue could not read")))))]
pub async fn list_plans(State(d): St, Query(p): Query<Page>) -> Result<Response, ApiError> {
    let (limit, offset) = p.get()?;
    Ok(listing(d.store().plans(limit, offset)?))
}

/// One plan: its state, the step it is at, the operator's prompt, its
/// captures, its reconstruction and every step.
#[utoipa::path(get, path = "/plans/{id}", params(("id" = String, Path, description = "The plan's id, a positive whole number")), responses((status = 200, body = crate::daemon::PlanView), (status = 404, description = "No such plan")))]
pub async fn get_plan(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<crate::daemon::PlanView>, ApiError> {
    Ok(Json(d.plans().plan_view(parse_id(&id, "plan")?)?))
}

/// Cancels a plan that has not ended (and the capture or reconstruction it
/// waits on); the captures it took are kept.
#[utoipa::path(delete, path = "/plans/{id}", params(("id" = String, Path, description = "The plan's id, a positive whole number")), responses((status = 200, body = crate::daemon::PlanView), (status = 404, description = "No such plan"), (status = 409, description = "It already ended")))]
pub async fn cancel_plan(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<crate::daemon::PlanView>, ApiError> {
    Ok(Json(d.plans().cancel_plan(parse_id(&id, "plan")?).await?))
}

/// The operator did what the plan's prompt asked: it goes on.
#[utoipa::path(post, path = "/plans/{id}/continue", params(("id" = String, Path, description = "The plan's id, a positive whole number")), responses((status = 200, body = crate::daemon::PlanView), (status = 404, description = "No such plan"), (status = 409, description = "It is not waiting for the operator")))]
pub async fn continue_plan(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<crate::daemon::PlanView>, ApiError> {
    Ok(Json(d.plans().continue_plan(parse_id(&id, "plan")?)?))
}
