//! The page and its API: each handler does what one command of the CLI does, with that
//! command's code, and answers JSON (errors as `{result, error}` in the CLI's words).

use std::convert::Infallible;
use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Path, Query, State};
use axum::http::{StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use futures_util::Stream;
use openlcb_cdi::Layout;
use openlcb_stream::NodeId;
use openlcb_tokio::NodeCommand;
use serde::Deserialize;
use serde_json::{Value as Json, json};
use tokio::sync::{broadcast, watch};

use super::live::{self, Identified};
use super::{ApiError, Job, MAX_BODY_BYTES, MAX_FIRMWARE_BYTES, Shared};
use crate::config::{self, Session};
use crate::memory::{self, Moved};
use crate::net;
use crate::outcome::{Failure, Missing};

/// The page's files, embedded.
const INDEX_HTML: &str = include_str!("page/index.html");
const APP_JS: &str = include_str!("page/app.js");
const STYLE_CSS: &str = include_str!("page/style.css");

/// How long a node's answers to Identify Events are waited for, after the last one.
const IDENTIFY_QUIET: Duration = Duration::from_millis(1000);

/// The state every handler takes.
type Ctx = State<Arc<Shared>>;

/// The page and the API, behind the guard.
pub(super) fn router(shared: Arc<Shared>) -> Router {
    let firmware = post(firmware).layer(DefaultBodyLimit::max(MAX_FIRMWARE_BYTES));
    Router::new()
        .route("/", get(|| async { page(INDEX_HTML, "text/html; charset=utf-8") }))
        .route("/app.js", get(|| async { page(APP_JS, "text/javascript; charset=utf-8") }))
        .route("/style.css", get(|| async { page(STYLE_CSS, "text/css; charset=utf-8") }))
        .route("/api/state", get(state))
        .route("/api/live", get(live_stream))
        .route("/api/nodes/refresh", post(refresh))
        .route("/api/nodes/{node}", get(node_info))
        .route("/api/nodes/{node}/config", get(config_show).post(config_save))
        .route("/api/nodes/{node}/backup", get(backup))
        .route("/api/nodes/{node}/restore", post(restore))
        .route("/api/nodes/{node}/command/{command}", post(command))
        .route("/api/nodes/{node}/firmware", firmware)
        .route("/api/nodes/{node}/events", post(node_events))
        .route("/api/events/send", post(send_event))
        .route("/api/events/identify", post(identify_all))
        .route("/api/cancel", post(cancel))
        .route("/api/clock", get(clock_state).post(clock_set))
        .route("/api/throttle", get(throttle_state).post(throttle_ask))
        .route("/api/monitor/trace", get(trace))
        .fallback(|| async { ApiError::new(StatusCode::NOT_FOUND, "not_found", "no such page") })
        .layer(DefaultBodyLimit::max(MAX_BODY_BYTES))
        .layer(axum::middleware::from_fn_with_state(Arc::clone(&shared), super::guard))
        .with_state(shared)
}

fn page(body: &'static str, kind: &'static str) -> Response {
    ([(header::CONTENT_TYPE, kind)], body).into_response()
}

/// The Node ID in a path, or a 400 that says which forms are taken.
fn peer(text: &str) -> Result<NodeId, ApiError> {
    crate::args::node_id(text).map_err(|e| ApiError::usage(format!("`{text}`: {e}")))
}

/// Clears the running job when the operation ends (also when the request is dropped).
struct JobGuard<'a>(&'a Shared);

impl Drop for JobGuard<'_> {
    fn drop(&mut self) {
        *self.0.job() = None;
        self.0.push("job", &Json::Null);
    }
}

/// Runs `operation` as the one operation on the bus, shown to every page as `what` with its
/// progress, cancelled by the Cancel button. Another one running is a 409.
async fn job<T, F, Fut>(shared: &Shared, what: String, operation: F) -> Result<T, ApiError>
where
    F: FnOnce(net::Interrupt) -> Fut,
    Fut: Future<Output = Result<T, ApiError>>,
{
    let Ok(_busy) = shared.busy.try_lock() else {
        let running = shared.job().as_ref().map_or_else(String::new, |job| job.what.clone());
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "busy",
            format!("another operation is running ({running}); wait for it or cancel it"),
        ));
    };
    shared.cancel.send_replace(false);
    let (progress, mut moved) = watch::channel((0u64, None));
    let started = Job { what, bytes: 0, total: None };
    *shared.job() = Some(started.clone());
    shared.push("job", &started);
    let _guard = JobGuard(shared);
    let interrupt = net::Interrupt::on(shared.cancel.subscribe(), progress);
    let run = operation(interrupt);
    tokio::pin!(run);
    loop {
        tokio::select! {
            result = &mut run => return result,
            Ok(()) = moved.changed() => {
                let (bytes, total) = *moved.borrow_and_update();
                let job = {
                    let mut job = shared.job();
                    if let Some(job) = job.as_mut() {
                        job.bytes = bytes;
                        job.total = total;
                    }
                    job.clone()
                };
                shared.push("job", &job);
            }
        }
    }
}

/// `peer`'s CDI laid out: read once (by the caller's job), then kept until Refresh.
async fn layout(shared: &Shared, peer: NodeId, interrupt: &mut net::Interrupt) -> Result<Arc<Layout>, ApiError> {
    if let Some(layout) = shared.layouts.lock().await.get(&peer) {
        return Ok(Arc::clone(layout));
    }
    memory::find(&shared.node, peer).await?;
    let layout = Arc::new(config::read_layout(&shared.node, peer, &shared.client, interrupt).await?);
    shared.layouts.lock().await.insert(peer, Arc::clone(&layout));
    Ok(layout)
}

/// What a page needs when it opens.
async fn state(State(shared): Ctx) -> axum::Json<Json> {
    let nodes: Vec<_> = shared.nodes().values().cloned().collect();
    let gathered = shared.gathered();
    axum::Json(json!({
        "node_id": shared.node.node_id().to_string(),
        "nodes": nodes,
        "reports": gathered.reports,
        "identified": gathered.identified,
        "lines": gathered.lines,
        "monitor_off": gathered.monitor_off,
        "trace_dropped": gathered.trace_dropped,
        "job": *shared.job(),
    }))
}

/// The pushes as server-sent events; a page that falls behind is told how many it missed.
async fn live_stream(State(shared): Ctx) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let receiver = shared.push.subscribe();
    let stream = futures_util::stream::unfold(receiver, |mut receiver| async move {
        let event = match receiver.recv().await {
            Ok(push) => Event::default().event(push.kind).data(push.data),
            Err(broadcast::error::RecvError::Lagged(skipped)) => {
                Event::default().event("skipped").data(skipped.to_string())
            }
            Err(broadcast::error::RecvError::Closed) => return None,
        };
        Some((Ok(event), receiver))
    });
    Sse::new(stream).keep_alive(KeepAlive::default())
}

/// Forgets the CDIs read and finds the nodes again.
async fn refresh(State(shared): Ctx) -> axum::Json<Json> {
    shared.layouts.lock().await.clear();
    live::discover(Arc::clone(&shared)).await;
    let nodes: Vec<_> = shared.nodes().values().cloned().collect();
    axum::Json(json!({ "nodes": nodes }))
}

/// SNIP and PIP of one node, asked now.
async fn node_info(State(shared): Ctx, Path(node): Path<String>) -> Result<axum::Json<Json>, ApiError> {
    let peer = peer(&node)?;
    let report = crate::nodes::describe(&shared.node, peer).await;
    if report.snip.is_some() || report.protocols.is_some() {
        // It answered: it is on the bus.
        live::learn(Arc::clone(&shared), peer).await;
    }
    Ok(axum::Json(json!(report)))
}

/// `config show --json`: the CDI's tree with every value.
async fn config_show(State(shared): Ctx, Path(node): Path<String>) -> Result<axum::Json<Json>, ApiError> {
    let peer = peer(&node)?;
    let what = format!("reading the configuration of {peer}");
    let shared: &Shared = &shared;
    job(shared, what, |mut interrupt| async move {
        let layout = layout(shared, peer, &mut interrupt).await?;
        let session = Session::with_layout(&shared.node, &shared.client, peer, layout);
        let done = session.show(&mut interrupt).await?;
        Ok(axum::Json(done.fields))
    })
    .await
}

/// The changes of a Save.
#[derive(Debug, Deserialize)]
struct Changes {
    changes: Vec<Change>,
}

#[derive(Debug, Deserialize)]
struct Change {
    key: String,
    value: String,
}

/// `config set` of every change at once: all checked before anything is written, each
/// written read back and compared, then Update Complete.
async fn config_save(State(shared): Ctx, Path(node): Path<String>, body: Bytes) -> Result<axum::Json<Json>, ApiError> {
    let peer = peer(&node)?;
    let changes: Changes = serde_json::from_slice(&body).map_err(|e| ApiError::usage(format!("the changes: {e}")))?;
    let changes: Vec<(String, String)> = changes.changes.into_iter().map(|c| (c.key, c.value)).collect();
    let what = format!("writing {} setting(s) of {peer}", changes.len());
    let owner = Arc::clone(&shared);
    let shared: &Shared = &shared;
    let answer = job(shared, what, |mut interrupt| async move {
        let layout = layout(shared, peer, &mut interrupt).await?;
        let session = Session::with_layout(&shared.node, &shared.client, peer, layout);
        let (written, warning) = session.set_many(&changes, &mut interrupt).await?;
        Ok(axum::Json(json!({ "result": "ok", "written": written, "warning": warning })))
    })
    .await;
    // Its name may have changed: the table asks it again.
    tokio::spawn(live::learn(Arc::clone(&owner), peer));
    answer
}

/// `config backup`: the file, byte for byte.
async fn backup(State(shared): Ctx, Path(node): Path<String>) -> Result<Response, ApiError> {
    let peer = peer(&node)?;
    let what = format!("backing up {peer}");
    let shared: &Shared = &shared;
    let text = job(shared, what, |mut interrupt| async move {
        let layout = layout(shared, peer, &mut interrupt).await?;
        let session = Session::with_layout(&shared.node, &shared.client, peer, layout);
        Ok(session.backup(&mut interrupt).await?)
    })
    .await?;
    let name = format!("attachment; filename=\"config-{}.txt\"", peer.to_string().replace('.', "-"));
    Ok(([(header::CONTENT_TYPE, "text/plain; charset=utf-8".to_string()), (header::CONTENT_DISPOSITION, name)], text)
        .into_response())
}

#[derive(Debug, Deserialize)]
struct RestoreQuery {
    /// Write the plan (else only show it).
    #[serde(default)]
    apply: bool,
}

/// `config restore` of the uploaded backup: its plan, and with `apply=true` the writes.
async fn restore(
    State(shared): Ctx,
    Path(node): Path<String>,
    Query(query): Query<RestoreQuery>,
    body: Bytes,
) -> Result<axum::Json<Json>, ApiError> {
    let peer = peer(&node)?;
    let text =
        String::from_utf8(body.to_vec()).map_err(|e| ApiError::usage(format!("the backup: not UTF-8 text ({e})")))?;
    let what = if query.apply { format!("restoring {peer}") } else { format!("comparing a backup with {peer}") };
    let owner = Arc::clone(&shared);
    let shared: &Shared = &shared;
    let answer = job(shared, what, |mut interrupt| async move {
        let layout = layout(shared, peer, &mut interrupt).await?;
        let most = openlcb_cdi::backup::max_backup_bytes(&layout);
        if text.len() > most {
            return Err(ApiError::usage(format!(
                "nothing written; the backup is larger than a backup of this node's CDI can be ({most} bytes)"
            )));
        }
        let session = Session::with_layout(&shared.node, &shared.client, peer, layout);
        let plan = session.restore_plan(&text, &mut interrupt).await?;
        let writes: Vec<Json> = plan
            .writes
            .iter()
            .map(|c| json!({ "key": c.entry.key, "old": c.old.to_string(), "new": c.new.to_string() }))
            .collect();
        let warning = if query.apply { session.apply(&plan, &mut interrupt).await? } else { None };
        Ok(axum::Json(json!({
            "result": "ok",
            "applied": query.apply,
            "writes": writes,
            "unchanged": plan.unchanged,
            "unknown_keys": plan.unknown_keys,
            "warning": warning,
        })))
    })
    .await;
    if query.apply {
        tokio::spawn(live::learn(owner, peer));
    }
    answer
}

#[derive(Debug, Default, Deserialize)]
struct Confirm {
    /// A factory reset is sent only with `"yes": true`.
    #[serde(default)]
    yes: bool,
}

/// Update Complete, Reboot or Factory Reset, as `reboot` and `factory-reset` send them.
async fn command(
    State(shared): Ctx,
    Path((node, command)): Path<(String, String)>,
    body: Bytes,
) -> Result<axum::Json<Json>, ApiError> {
    let peer = peer(&node)?;
    let confirm: Confirm = if body.is_empty() {
        Confirm::default()
    } else {
        serde_json::from_slice(&body).map_err(|e| ApiError::usage(format!("the request: {e}")))?
    };
    let (sent, done) = match command.as_str() {
        "update-complete" => (NodeCommand::UpdateComplete, format!("{peer} accepted Update Complete")),
        "reboot" => (NodeCommand::Reboot, format!("{peer} accepted the reboot")),
        "factory-reset" if confirm.yes => {
            (NodeCommand::FactoryReset, format!("{peer} accepted the factory reset (its settings are not read back)"))
        }
        "factory-reset" => {
            return Err(ApiError::usage(format!(
                "nothing sent: a factory reset puts every setting of {peer} back to its default; confirm it"
            )));
        }
        other => return Err(ApiError::new(StatusCode::NOT_FOUND, "not_found", format!("no command `{other}`"))),
    };
    let what = format!("{command} of {peer}");
    let shared: &Shared = &shared;
    job(shared, what, |mut interrupt| async move {
        memory::find(&shared.node, peer).await?;
        let transfer = shared.node.send_command(peer, sent).await.map_err(Failure::Net)?;
        memory::follow(&shared.node, transfer, None, true, &shared.client.pace, &mut interrupt, &mut Moved::default())
            .await?;
        if !matches!(sent, NodeCommand::UpdateComplete) {
            // Its settings or its CDI may change with the restart.
            shared.layouts.lock().await.remove(&peer);
        }
        Ok(axum::Json(json!({ "result": "ok", "message": done })))
    })
    .await
}

/// `firmware`: the uploaded image into space 0xEF between Freeze and Unfreeze.
async fn firmware(State(shared): Ctx, Path(node): Path<String>, body: Bytes) -> Result<axum::Json<Json>, ApiError> {
    let peer = peer(&node)?;
    if body.is_empty() {
        return Err(ApiError::usage("the firmware image is empty"));
    }
    let total = body.len() as u64;
    let what = format!("upgrading the firmware of {peer} ({total} bytes)");
    let started = std::time::Instant::now();
    let shared: &Shared = &shared;
    job(shared, what, |mut interrupt| async move {
        memory::find(&shared.node, peer).await?;
        let mut moved = Moved::default();
        let transfer = shared.node.upgrade_firmware(peer, body.to_vec(), shared.client.path()).await;
        let written = match transfer {
            Ok(transfer) => {
                memory::follow(
                    &shared.node,
                    transfer,
                    Some(total),
                    true,
                    &shared.client.pace,
                    &mut interrupt,
                    &mut moved,
                )
                .await
            }
            Err(error) => Err(Failure::Net(error)),
        };
        shared.layouts.lock().await.remove(&peer);
        match written {
            Ok(_) => {
                let elapsed = started.elapsed().as_secs_f64();
                let rate = net::rate_text(net::rate(total, elapsed));
                let message = format!("upgraded {peer} with {total} bytes in {elapsed:.3} s ({rate})");
                Ok(axum::Json(json!({ "result": "ok", "message": message, "bytes": total })))
            }
            Err(Failure::Interrupted) => Err(ApiError::of(
                crate::outcome::Outcome::Interrupted,
                format!("cancelled; {}", memory::FIRMWARE_INTERRUPTED),
            )),
            Err(failure) => {
                Err(memory::name_what_is_missing(&shared.node, peer, failure, Missing::FirmwareUpgrade).await.into())
            }
        }
    })
    .await
}

/// What `peer` produces and consumes: Identify Events sent to it, the answers gathered
/// until [`IDENTIFY_QUIET`] passes without one.
async fn node_events(State(shared): Ctx, Path(node): Path<String>) -> Result<axum::Json<Json>, ApiError> {
    let peer = peer(&node)?;
    let name = crate::peer::Peer::of(peer).to_string();
    let count = || shared.gathered().identified.iter().filter(|i| i.node == name).count();
    shared.node.identify_events(Some(peer)).await.map_err(Failure::Net)?;
    // Bounded: a round without a new answer ends it, and there are at most 30 rounds.
    let mut seen = usize::MAX;
    for _ in 0..30 {
        tokio::time::sleep(IDENTIFY_QUIET).await;
        let now = count();
        if now == seen {
            break;
        }
        seen = now;
    }
    let rows: Vec<Identified> = shared.gathered().identified.iter().filter(|i| i.node == name).cloned().collect();
    Ok(axum::Json(json!({ "identified": rows })))
}

#[derive(Debug, Deserialize)]
struct SendEvent {
    event: String,
    #[serde(default)]
    payload: String,
}

/// `events send`.
async fn send_event(State(shared): Ctx, body: Bytes) -> Result<axum::Json<Json>, ApiError> {
    let request: SendEvent = serde_json::from_slice(&body).map_err(|e| ApiError::usage(format!("the request: {e}")))?;
    let event = crate::events::event_id(request.event.trim()).map_err(ApiError::usage)?;
    let payload = crate::events::parse_payload(&request.payload).map_err(ApiError::usage)?;
    shared.node.send_event(event, payload).await.map_err(Failure::Net)?;
    Ok(axum::Json(json!({ "result": "ok", "message": format!("sent {}", crate::events::event_text(event)) })))
}

/// `events identify`: the answers come as `identified` pushes.
async fn identify_all(State(shared): Ctx) -> Result<axum::Json<Json>, ApiError> {
    shared.node.identify_events(None).await.map_err(Failure::Net)?;
    Ok(axum::Json(json!({ "result": "ok" })))
}

/// The Cancel button.
async fn cancel(State(shared): Ctx) -> axum::Json<Json> {
    let running = shared.job().is_some();
    shared.cancel.send_replace(true);
    axum::Json(json!({ "result": "ok", "cancelled": running }))
}

/// The trace, as `monitor --from` reads it.
async fn trace(State(shared): Ctx) -> Response {
    let text = {
        let gathered = shared.gathered();
        let mut text = String::new();
        if gathered.trace_dropped > 0 {
            text.push_str(&format!("# {} older frames were dropped\n", gathered.trace_dropped));
        }
        for line in &gathered.trace {
            text.push_str(line);
            text.push('\n');
        }
        text
    };
    let disposition = "attachment; filename=\"lcc-trace.txt\"";
    ([(header::CONTENT_TYPE, "text/plain; charset=utf-8"), (header::CONTENT_DISPOSITION, disposition)], text)
        .into_response()
}

/// The fast clock now.
async fn clock_state(State(shared): Ctx) -> axum::Json<Json> {
    axum::Json(json!(live::clock_view(&shared).await))
}

/// What a clock button asks: exactly one of them.
#[derive(Debug, Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
enum ClockAsk {
    Start,
    Stop,
    /// A rate, as `clock rate` takes it (`4`, `0.25`, `-2`).
    Rate(String),
    /// A time of day, `HH:MM`.
    Time(String),
}

/// `clock start`, `stop`, `rate` and `set --time`: sent to the generator, whose
/// confirmation is waited for.
async fn clock_set(State(shared): Ctx, body: Bytes) -> Result<axum::Json<Json>, ApiError> {
    use openlcb_tokio::openlcb_node::broadcast_time::ClockSet;
    let ask: ClockAsk = serde_json::from_slice(&body).map_err(|e| ApiError::usage(format!("the request: {e}")))?;
    let set = match ask {
        ClockAsk::Start => ClockSet::Start,
        ClockAsk::Stop => ClockSet::Stop,
        ClockAsk::Rate(rate) => ClockSet::Rate(crate::clock::parse_rate(rate.trim()).map_err(ApiError::usage)?),
        ClockAsk::Time(time) => {
            let (hour, minute) = crate::clock::parse_time(time.trim()).map_err(ApiError::usage)?;
            ClockSet::Time { hour, minute }
        }
    };
    let mut notices = shared.node.event_notices().await.map_err(Failure::Net)?;
    match crate::clock::set_confirmed(&shared.node, &mut notices, shared.clock, set).await {
        Ok(message) => Ok(axum::Json(json!({ "result": "ok", "message": message }))),
        Err(crate::clock::Unconfirmed::Net(failure)) => Err(failure.into()),
        Err(crate::clock::Unconfirmed::NoGenerator(words)) => {
            Err(ApiError::of(crate::outcome::Outcome::TimedOut, words))
        }
    }
}

/// The train the throttle pane holds.
async fn throttle_state(State(shared): Ctx) -> axum::Json<Json> {
    let held = *shared.train.lock().await;
    axum::Json(match held {
        Some((train, address)) => json!({ "train": train.to_string(), "address": address }),
        None => json!({ "train": null }),
    })
}

/// What a throttle control asks: exactly one of them.
#[derive(Debug, Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
enum ThrottleAsk {
    /// Find the train of this DCC address (allocating it) and take it, as `throttle` does.
    Acquire {
        /// 1 to 10239.
        address: u32,
        /// The long (14-bit) address.
        #[serde(default)]
        long: bool,
    },
    /// The speed in km/h (scale); negative runs in reverse.
    Speed(f32),
    /// A function and its state.
    Function { number: u32, on: bool },
    /// Emergency stop.
    Estop,
    /// Give the train back.
    Release,
}

/// The throttle pane's controls: the same commands as `lcc-stream throttle`, each read back
/// from the train (Query Speeds, Query Function) before it is said done.
async fn throttle_ask(State(shared): Ctx, body: Bytes) -> Result<axum::Json<Json>, ApiError> {
    use crate::outcome::Outcome;
    use crate::peer::Peer;
    use crate::throttle::{NotAcquired, acquire, send, wait_for};
    use openlcb_tokio::openlcb_node::traction::{Speed, ThrottleEvent, TractionCommand};
    let ask: ThrottleAsk = serde_json::from_slice(&body).map_err(|e| ApiError::usage(format!("the request: {e}")))?;
    let mut held = shared.train.lock().await;
    let node = &shared.node;
    let mut events = node.throttle_events().await.map_err(Failure::Net)?;
    let not_held = || ApiError::of(Outcome::Usage, "no train is held: acquire one first".into());
    let (train, address) = match ask {
        ThrottleAsk::Acquire { address, long } => {
            if !(1..=10239).contains(&address) {
                return Err(ApiError::usage("a DCC address is 1 to 10239"));
            }
            if let Some((train, _)) = held.take() {
                send(node, train, TractionCommand::ReleaseController { flags: 0, node: node.node_id() }).await?;
            }
            let mut notices = node.event_notices().await.map_err(Failure::Net)?;
            let train = match acquire(node, &mut notices, &mut events, address, long).await {
                Ok(train) => train,
                Err(NotAcquired::Net(failure)) => return Err(failure.into()),
                Err(NotAcquired::Refused(why)) => return Err(ApiError::of(Outcome::Rejected, why)),
                Err(NotAcquired::TimedOut(why)) => return Err(ApiError::of(Outcome::TimedOut, why)),
            };
            *held = Some((train, address));
            let message = format!("DCC {address} is {}", Peer::of(train));
            return Ok(axum::Json(json!({ "result": "ok", "train": train.to_string(), "message": message })));
        }
        ThrottleAsk::Release => {
            let (train, address) = held.take().ok_or_else(not_held)?;
            send(node, train, TractionCommand::ReleaseController { flags: 0, node: node.node_id() }).await?;
            let message = format!("DCC {address} ({}) released", Peer::of(train));
            return Ok(axum::Json(json!({ "result": "ok", "message": message })));
        }
        _ => (*held).ok_or_else(not_held)?,
    };
    let (command, query) = match ask {
        ThrottleAsk::Speed(kmh) if kmh.is_finite() && kmh.abs() <= 1000.0 => {
            let magnitude = Speed::from_f32(kmh.abs() / 3.6);
            let speed = if kmh < 0.0 { magnitude.reversed() } else { magnitude };
            (TractionCommand::SetSpeed { speed, forwarded: false }, TractionCommand::QuerySpeeds)
        }
        ThrottleAsk::Function { number, on } if number <= 68 => (
            TractionCommand::SetFunction { address: number, value: u16::from(on), forwarded: false },
            TractionCommand::QueryFunction { address: number },
        ),
        ThrottleAsk::Estop => (TractionCommand::EmergencyStop { forwarded: false }, TractionCommand::QuerySpeeds),
        ThrottleAsk::Speed(_) => return Err(ApiError::usage("a speed is -1000 to 1000 km/h")),
        _ => return Err(ApiError::usage("a function is F0 to F68")),
    };
    send(node, train, command).await?;
    send(node, train, query).await?;
    // What the train holds now, in its own answer.
    let read_back = wait_for(&mut events, |e| match *e {
        ThrottleEvent::Speeds { train: t, set, emergency_stop, .. } if t == train => Some(Ok(match emergency_stop {
            true => format!("emergency stop (speed {:.0} km/h)", set.to_f32() * 3.6),
            false => format!("speed {:.0} km/h", set.to_f32() * 3.6),
        })),
        ThrottleEvent::Function { train: t, address, value } if t == train => {
            Some(Ok(format!("F{address} {}", if value == 0 { "off" } else { "on" })))
        }
        ThrottleEvent::Rejected { train: t, code } if t == train => {
            Some(Err(ApiError::of(Outcome::Rejected, format!("{} refused it (0x{:04X})", Peer::of(train), code.0))))
        }
        ThrottleEvent::TrainLost { train: t } if t == train => {
            Some(Err(ApiError::of(Outcome::NotFound, format!("{} left the network", Peer::of(train)))))
        }
        _ => None,
    })
    .await
    .ok_or_else(|| ApiError::of(Outcome::TimedOut, format!("{} did not answer the query", Peer::of(train))))??;
    let message = format!("DCC {address} ({}): {read_back}", Peer::of(train));
    Ok(axum::Json(json!({ "result": "ok", "message": message })))
}
