//! `lcc-stream ui`: the layout in a browser. The tool joins the bus as one node, serves a
//! page (embedded in the binary: plain HTML, CSS and JavaScript, nothing fetched from
//! elsewhere) and an HTTP API, and pushes what happens on the bus to the page by server-sent
//! events.
//!
//! Everything the page shows and does goes through the code of the other commands: `nodes`
//! (SNIP and PIP), `config` (the CDI, its values, verified writes, JMRI backups and
//! restores), `reboot` and `factory-reset`, `firmware`, `events` and `monitor`'s decoder.
//!
//! Security: on 127.0.0.1 (the default) a request is served only with a `Host` of the
//! loopback (no DNS rebinding), and one that changes anything only with the header
//! `X-LCC-UI` and no foreign `Origin` (no cross-site request can set it). On any other
//! address every API request also needs the token printed in the URL. See README.

mod api;
mod live;

use std::collections::{BTreeMap, HashMap};
use std::net::SocketAddr;
use std::process::ExitCode;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use clap::Args;
use openlcb_cdi::Layout;
use openlcb_stream::{AcceptPolicy, NodeId, wire::ReplyCode};
use openlcb_tokio::openlcb_node::broadcast_time::ClockId;
use openlcb_tokio::{Listen, Node, NodeOptions};
use serde::Serialize;
use tokio::sync::{broadcast, watch};

use crate::memory::ClientArgs;
use crate::net;
use crate::nodes::NodeReport;
use crate::outcome::Outcome;

/// The header a request that changes anything must carry (its value is the token when
/// there is one): a page of another site cannot send it without a CORS preflight, which
/// is never granted.
pub(crate) const UI_HEADER: &str = "x-lcc-ui";

/// How long requests still running at Ctrl-C may take to end.
const SHUTDOWN_GRACE: std::time::Duration = std::time::Duration::from_secs(2);

/// The most bytes of a firmware image taken from the browser.
pub(crate) const MAX_FIRMWARE_BYTES: usize = 16 * 1024 * 1024;
/// The most bytes of any other request body (a list of changes, a backup).
pub(crate) const MAX_BODY_BYTES: usize = 4 * 1024 * 1024;

/// Options of `lcc-stream ui`.
#[derive(Debug, Args)]
#[command(after_help = after_help())]
pub(crate) struct UiArgs {
    /// Where the page is served, ADDR:PORT (port 0: any free port). An address other than the
    /// loopback (127.0.0.1, ::1) lets others on the network reach the page: then every API
    /// request needs the token printed in the URL.
    #[arg(long, value_name = "ADDR:PORT", default_value = "127.0.0.1:8080")]
    listen: SocketAddr,
    /// Require the token on the loopback too (a computer whose other users should not
    /// configure the layout); beyond the loopback it is always required.
    #[arg(long)]
    token: bool,
    /// The fast clock the page shows and drives: default-fast, default-realtime,
    /// alternate-1, alternate-2 or six hex bytes.
    #[arg(long, default_value = "default-fast", value_parser = crate::clock::parse_clock)]
    clock: ClockId,
    #[command(flatten)]
    client: ClientArgs,
}

/// Does a page served on `listen` need a token? Beyond the loopback always.
fn needs_token(listen: &SocketAddr, asked: bool) -> bool {
    asked || !listen.ip().is_loopback()
}

fn after_help() -> String {
    format!(
        "\
Prints the page's URL on stdout (with --json one object: url, listen, token, node_id) and
serves until Ctrl-C. The page: the nodes (SNIP, PIP), each node's configuration from its CDI
(every write read back and compared, as `config set`), backup and restore in JMRI's format,
Update Complete, Reboot, Factory Reset, firmware upgrade, its events; the event reports of the
bus; the decoded bus (as `monitor`), with a download of the trace in the form `monitor --from`
reads.

On 127.0.0.1 (the default) anyone who can open a connection to 127.0.0.1 on this computer can
use the page (--token asks for a token there too); pages of other sites cannot (a change needs
the header X-LCC-UI, and the Host and Origin must be this page's). With --listen on another
address, the URL carries a token (a new one each run): without it the API answers 403.

{}",
        net::network_help(&[])
    )
}

/// What `--json` prints once the page is served.
#[derive(Debug, Serialize)]
struct Ready {
    url: String,
    listen: String,
    token: Option<String>,
    node_id: String,
}

/// One message to the open pages.
#[derive(Debug, Clone)]
pub(crate) struct Push {
    /// The event's name (`nodes`, `event`, `identified`, `monitor`, `job`, `progress`).
    pub(crate) kind: &'static str,
    /// Its data, JSON.
    pub(crate) data: String,
}

/// The operation running on the bus (one at a time: the page shows it, with Cancel).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct Job {
    /// What it is, in words (`reading the configuration of 05.01.01.01.22.E2`).
    pub(crate) what: String,
    /// Bytes moved by its current transfer, of how many (if known).
    pub(crate) bytes: u64,
    pub(crate) total: Option<u64>,
}

/// Everything the server shares.
pub(crate) struct Shared {
    /// The tool's node on the bus.
    pub(crate) node: Node,
    /// How operations run (`--no-stream`, the pace rule); `json`: no progress bars.
    pub(crate) client: ClientArgs,
    /// The token every API request needs, beyond the loopback.
    pub(crate) token: Option<String>,
    /// The addresses the page may be asked for by (`Host`), on the loopback.
    pub(crate) hosts: Vec<String>,
    /// The nodes seen, by Node ID.
    pub(crate) nodes: Mutex<BTreeMap<NodeId, NodeReport>>,
    /// CDIs read, laid out.
    pub(crate) layouts: tokio::sync::Mutex<HashMap<NodeId, Arc<Layout>>>,
    /// Held while an operation runs on the bus.
    pub(crate) busy: tokio::sync::Mutex<()>,
    /// The running operation, if any.
    pub(crate) job: Mutex<Option<Job>>,
    /// Set to cancel the running operation.
    pub(crate) cancel: watch::Sender<bool>,
    /// To the open pages.
    pub(crate) push: broadcast::Sender<Push>,
    /// What the monitor and the event watch have gathered.
    pub(crate) live: Mutex<live::Gathered>,
    /// The fast clock the page shows.
    pub(crate) clock: ClockId,
    /// The train the throttle pane holds (this node is its controller), and its address.
    pub(crate) train: tokio::sync::Mutex<Option<(NodeId, u32)>>,
}

impl Shared {
    /// Sends `data` as `kind` to every open page.
    pub(crate) fn push(&self, kind: &'static str, data: &impl Serialize) {
        let data = net::json_line(data).trim_end().to_string();
        // No page open is no error.
        let _ = self.push.send(Push { kind, data });
    }

    /// The nodes table, locked.
    pub(crate) fn nodes(&self) -> MutexGuard<'_, BTreeMap<NodeId, NodeReport>> {
        self.nodes.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// What the monitor and the event watch have gathered, locked.
    pub(crate) fn gathered(&self) -> MutexGuard<'_, live::Gathered> {
        self.live.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The running job, locked.
    pub(crate) fn job(&self) -> MutexGuard<'_, Option<Job>> {
        self.job.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// 128 random bits in hex.
fn new_token() -> Result<String, String> {
    let mut bytes = [0u8; 16];
    getrandom::fill(&mut bytes).map_err(|e| format!("cannot make a token: {e}"))?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// Equal, in a time that does not depend on where they differ.
fn same_secret(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

pub(crate) fn run(args: &UiArgs) -> Result<ExitCode, String> {
    net::runtime()?.block_on(serve(args))
}

async fn serve(args: &UiArgs) -> Result<ExitCode, String> {
    let mut interrupt = net::Interrupt::new()?;
    let token = if needs_token(&args.listen, args.token) { Some(new_token()?) } else { None };
    let listener = match tokio::net::TcpListener::bind(args.listen).await {
        Ok(listener) => listener,
        Err(error) => {
            eprintln!("lcc-stream ui: cannot listen on {}: {error}", args.listen);
            return Ok(ExitCode::from(Outcome::Error.status()));
        }
    };
    let local = listener.local_addr().map_err(|e| format!("cannot listen on {}: {e}", args.listen))?;
    let mut client = args.client.clone();
    let json = client.json;
    // No progress bars on the terminal: the page shows the progress.
    client.json = true;
    let node = client.connect.join(&client.node_id, |id| {
        let mut options = NodeOptions::new(id);
        options.node.snip = net::snip("ui");
        options.node.stream.accept_policy = AcceptPolicy::RejectAll(ReplyCode::BUFFER_UNAVAILABLE);
        options.node.events.listen = Listen::Everything;
        options.node.clocks = vec![crate::clock::controlling_consumer(args.clock)];
        options.node.throttle = Some(openlcb_tokio::openlcb_node::traction::ThrottleConfig::default());
        options
    });
    let node = match node.await {
        Ok(node) => node,
        Err(failure) => return Ok(net::fail("ui", &failure)),
    };
    let port = local.port();
    let hosts = if local.ip().is_loopback() {
        vec![format!("127.0.0.1:{port}"), format!("localhost:{port}"), format!("[::1]:{port}")]
    } else {
        Vec::new()
    };
    let node_id = node.node_id();
    let (push, _) = broadcast::channel(4096);
    let shared = Arc::new(Shared {
        node,
        client,
        token: token.clone(),
        hosts,
        nodes: Mutex::new(BTreeMap::new()),
        layouts: tokio::sync::Mutex::new(HashMap::new()),
        busy: tokio::sync::Mutex::new(()),
        job: Mutex::new(None),
        cancel: watch::channel(false).0,
        push,
        live: Mutex::new(live::Gathered::default()),
        clock: args.clock,
        train: tokio::sync::Mutex::new(None),
    });
    let host = match local.ip() {
        std::net::IpAddr::V6(ip) => format!("[{ip}]:{port}"),
        std::net::IpAddr::V4(ip) if ip.is_unspecified() => format!("127.0.0.1:{port}"),
        std::net::IpAddr::V4(ip) => format!("{ip}:{port}"),
    };
    let url = match &token {
        Some(token) => format!("http://{host}/?token={token}"),
        None => format!("http://{host}/"),
    };
    let tasks = live::start(&shared, &args.client.connect);
    if json {
        net::print_json(&Ready { url: url.clone(), listen: local.to_string(), token, node_id: node_id.to_string() });
    } else {
        outln!("{url}");
        if !net::quiet() {
            eprintln!("lcc-stream ui: serving the page on {local} as node {node_id} (Ctrl-C stops)");
        }
    }
    let app = api::router(Arc::clone(&shared));
    let (stop, stopped) = watch::channel(false);
    let server = axum::serve(listener, app).with_graceful_shutdown(async move {
        let mut stopped = stopped;
        let _ = stopped.wait_for(|s| *s).await;
    });
    let server = server.into_future();
    tokio::pin!(server);
    let served = tokio::select! {
        served = &mut server => served,
        () = interrupt.wait() => {
            stop.send_replace(true);
            // An open page keeps its live updates open: requests get a moment, not forever.
            tokio::time::timeout(SHUTDOWN_GRACE, &mut server).await.unwrap_or(Ok(()))
        }
    };
    for task in tasks {
        task.abort();
    }
    // The node's last messages go out before the process ends.
    match Arc::try_unwrap(shared) {
        Ok(shared) => shared.node.close().await,
        Err(_) => tracing::info!("requests still held the node at the end"),
    }
    match served {
        Ok(()) => Ok(ExitCode::from(Outcome::Interrupted.status())),
        Err(error) => Err(format!("the page's server stopped: {error}")),
    }
}

/// An answer of the API that says what went wrong, in the CLI's words.
#[derive(Debug)]
pub(crate) struct ApiError {
    status: StatusCode,
    result: &'static str,
    error: String,
}

impl ApiError {
    pub(crate) fn new(status: StatusCode, result: &'static str, error: impl Into<String>) -> Self {
        ApiError { status, result, error: error.into() }
    }

    /// A request that cannot be taken as it is (400).
    pub(crate) fn usage(error: impl Into<String>) -> Self {
        ApiError::new(StatusCode::BAD_REQUEST, Outcome::Usage.word(), error)
    }

    /// A failure of an operation, by its outcome.
    pub(crate) fn of(outcome: Outcome, error: String) -> Self {
        let status = match outcome {
            Outcome::Usage => StatusCode::BAD_REQUEST,
            Outcome::TimedOut | Outcome::NotFound => StatusCode::GATEWAY_TIMEOUT,
            Outcome::Interrupted => StatusCode::CONFLICT,
            _ => StatusCode::BAD_GATEWAY,
        };
        ApiError::new(status, outcome.word(), error)
    }
}

impl From<crate::config::Failure> for ApiError {
    fn from(failure: crate::config::Failure) -> Self {
        ApiError::of(failure.outcome(), failure.to_string())
    }
}

impl From<crate::outcome::Failure> for ApiError {
    fn from(failure: crate::outcome::Failure) -> Self {
        let outcome = match failure {
            crate::outcome::Failure::Interrupted => Outcome::Interrupted,
            ref other => other.outcome(),
        };
        let error = match failure {
            crate::outcome::Failure::Interrupted => "cancelled".to_string(),
            other => other.to_string(),
        };
        ApiError::of(outcome, error)
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = serde_json::json!({ "result": self.result, "error": self.error });
        (self.status, axum::Json(body)).into_response()
    }
}

/// The token of a request: the header [`UI_HEADER`], or for a GET (a download, the event
/// stream, which cannot set headers) the query's `token`.
fn offered_token<'a>(method: &Method, headers: &'a HeaderMap, query: Option<&'a str>) -> Option<&'a str> {
    if let Some(value) = headers.get(UI_HEADER).and_then(|v| v.to_str().ok()) {
        return Some(value);
    }
    if method != Method::GET {
        return None;
    }
    query?.split('&').find_map(|pair| pair.strip_prefix("token="))
}

/// Why a request is refused before it is looked at, if it is.
fn refusal(shared: &Shared, request: &Request) -> Option<ApiError> {
    let headers = request.headers();
    let method = request.method();
    let host = headers.get(header::HOST).and_then(|v| v.to_str().ok()).unwrap_or_default();
    if !shared.hosts.is_empty() && !shared.hosts.iter().any(|h| h.eq_ignore_ascii_case(host)) {
        // A name that resolves to 127.0.0.1 (DNS rebinding) is not the loopback's page.
        return Some(ApiError::new(StatusCode::FORBIDDEN, "forbidden", format!("not served for the host `{host}`")));
    }
    let changes = !matches!(*method, Method::GET | Method::HEAD);
    if changes {
        if let Some(origin) = headers.get(header::ORIGIN).and_then(|v| v.to_str().ok())
            && origin != format!("http://{host}")
        {
            return Some(ApiError::new(
                StatusCode::FORBIDDEN,
                "forbidden",
                format!("a request from another origin ({origin}) is refused"),
            ));
        }
        if headers.get(UI_HEADER).is_none() {
            return Some(ApiError::new(
                StatusCode::FORBIDDEN,
                "forbidden",
                format!("a request that changes anything needs the header {UI_HEADER} (the page sends it)"),
            ));
        }
    }
    let api = request.uri().path().starts_with("/api/");
    if let (Some(token), true) = (&shared.token, api) {
        let offered = offered_token(method, headers, request.uri().query());
        if !offered.is_some_and(|o| same_secret(o.as_bytes(), token.as_bytes())) {
            return Some(ApiError::new(
                StatusCode::FORBIDDEN,
                "forbidden",
                "this page needs its token: open the URL that `lcc-stream ui` printed",
            ));
        }
    }
    None
}

/// Refuses what [`refusal`] refuses, and adds the headers that keep the page in its own
/// frame, its own origin and out of caches.
async fn guard(State(shared): State<Arc<Shared>>, request: Request, next: Next) -> Response {
    let mut response = match refusal(&shared, &request) {
        Some(error) => error.into_response(),
        None => next.run(request).await,
    };
    let headers = response.headers_mut();
    headers.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static("default-src 'self'; frame-ancestors 'none'; form-action 'self'"),
    );
    headers.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    headers.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    headers.insert(header::REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secrets_are_compared_whole() {
        assert!(same_secret(b"abc", b"abc"));
        assert!(!same_secret(b"abc", b"abd"));
        assert!(!same_secret(b"abc", b"abcd"));
    }

    #[test]
    fn a_token_comes_by_header_or_by_a_get_query() {
        let mut headers = HeaderMap::new();
        assert_eq!(offered_token(&Method::GET, &headers, Some("a=1&token=xyz")), Some("xyz"));
        assert_eq!(offered_token(&Method::POST, &headers, Some("token=xyz")), None);
        headers.insert(UI_HEADER, HeaderValue::from_static("t"));
        assert_eq!(offered_token(&Method::POST, &headers, None), Some("t"));
    }

    #[test]
    fn beyond_the_loopback_a_token_is_needed() {
        let at = |text: &str| text.parse::<SocketAddr>().unwrap();
        assert!(!needs_token(&at("127.0.0.1:8080"), false));
        assert!(!needs_token(&at("[::1]:8080"), false));
        assert!(needs_token(&at("127.0.0.1:8080"), true));
        for beyond in ["0.0.0.0:8080", "192.168.1.20:8080", "[::]:8080"] {
            assert!(needs_token(&at(beyond), false), "{beyond}");
        }
    }

    #[test]
    fn tokens_are_fresh_and_long() {
        let (a, b) = (new_token().unwrap(), new_token().unwrap());
        assert_eq!(a.len(), 32);
        assert_ne!(a, b);
    }
}
