//! `lcc-stream ui` against `serve` through an in-process hub on 127.0.0.1: its HTTP API (what
//! it refuses, what it writes, read back by the CLI), and the page in a real headless
//! Chromium driven by the DevTools protocol.
//!
//! The browser test needs Debian's `chromium` (CI installs it); without one it fails, unless
//! LCC_UI_BROWSER_TEST=skip. With LCC_UI_SCREENSHOTS=DIR it saves the screenshots of README
//! there (`.ci/ui-screenshots` does that). Every wait is bounded; children die with the test.

mod common;

use std::path::{Path, PathBuf};
use std::process::Stdio;

use common::{BIN, bounded, scratch};
use futures_util::{SinkExt as _, StreamExt as _};
use openlcb_tokio::{Hub, HubOptions};
use serde_json::{Value, json};
use tokio::io::{AsyncBufReadExt as _, AsyncReadExt as _, AsyncWriteExt as _, BufReader};
use tokio::process::{Child, Command};
use tokio_tungstenite::tungstenite::Message;

const SERVER: &str = "05.01.01.01.22.E2";
/// The event SERVER produces.
const PRODUCED: &str = "05.01.01.01.22.E2.00.01";
/// A Node ID nobody has.
const NOBODY: &str = "05.01.01.01.22.77";

/// A hub, `serve` as SERVER with a 256-byte configuration of zeros named "Yard", and `ui`.
struct Layout {
    _hub: Hub,
    hub: String,
    dir: PathBuf,
    config: PathBuf,
    _serve: Child,
    ui: Child,
    /// `http://127.0.0.1:PORT`.
    base: String,
    /// `127.0.0.1:PORT`.
    addr: String,
    token: Option<String>,
}

impl Layout {
    async fn start(test: &str, ui_args: &[&str]) -> Layout {
        Layout::sized(test, 256, ui_args).await
    }

    /// [`Layout::start`] with `len` bytes of configuration.
    async fn sized(test: &str, len: usize, ui_args: &[&str]) -> Layout {
        let dir = scratch(test);
        let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
        let addr = hub.local_addr().to_string();
        let config = dir.join("config.bin");
        std::fs::write(&config, vec![0; len]).unwrap();
        let serve = serve(&dir, &addr, SERVER, "Yard", &config, &["--produces", PRODUCED]).await;
        let (ui, listen, token) = start_ui(&addr, ui_args).await;
        Layout {
            _hub: hub,
            hub: addr,
            dir,
            config,
            _serve: serve,
            ui,
            base: format!("http://{listen}"),
            addr: listen,
            token,
        }
    }

    /// A request as the page makes it (the header, with the token if there is one).
    async fn page(&self, method: &str, path: &str, body: &[u8]) -> Answer {
        let header = format!("X-LCC-UI: {}\r\n", self.token.as_deref().unwrap_or("1"));
        http(&self.addr, method, path, &header, body).await
    }

    /// The page's request, which must succeed, as JSON.
    async fn ok(&self, method: &str, path: &str, body: &Value) -> Value {
        let body = if body.is_null() { Vec::new() } else { body.to_string().into_bytes() };
        let answer = self.page(method, path, &body).await;
        assert_eq!(answer.status, 200, "{method} {path}: {}", answer.text());
        answer.json()
    }

    /// The CLI with `args` and the hub: exit status, stdout, stderr.
    async fn cli(&self, args: &[&str]) -> (i32, String, String) {
        let output = Command::new(BIN)
            .args(args)
            .args(["--connect", &self.hub])
            .stdin(Stdio::null())
            .kill_on_drop(true)
            .output();
        let output = bounded(&args.join(" "), output).await.unwrap();
        let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
        (output.status.code().unwrap_or(-1), text(&output.stdout), text(&output.stderr))
    }

    /// `config get KEY` of SERVER.
    async fn get(&self, key: &str) -> String {
        let (status, out, err) = self.cli(&["config", "get", SERVER, key]).await;
        assert_eq!(status, 0, "{err}");
        out.trim_end_matches('\n').to_string()
    }
}

/// `ui --json` on the hub at `hub`: the child, the address it listens on and its token.
async fn start_ui(hub: &str, ui_args: &[&str]) -> (Child, String, Option<String>) {
    let mut ui = Command::new(BIN)
        .args(["ui", "--connect", hub, "--listen", "127.0.0.1:0", "--json"])
        .args(ui_args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut out = BufReader::new(ui.stdout.take().unwrap()).lines();
    let ready = bounded("ui to print its URL", out.next_line()).await.unwrap().expect("ui printed nothing");
    let ready: Value = serde_json::from_str(&ready).unwrap();
    let listen = ready["listen"].as_str().unwrap().to_string();
    assert!(listen.starts_with("127.0.0.1:"), "{ready}");
    let token = ready["token"].as_str().map(str::to_string);
    let url = ready["url"].as_str().unwrap();
    match &token {
        Some(token) => assert_eq!(url, format!("http://{listen}/?token={token}")),
        None => assert_eq!(url, format!("http://{listen}/")),
    }
    (ui, listen, token)
}

/// `serve` as `node_id` named `name` with the configuration file `config`, once it serves.
async fn serve(dir: &Path, hub: &str, node_id: &str, name: &str, config: &Path, extra: &[&str]) -> Child {
    let mut serve = Command::new(BIN)
        .current_dir(dir)
        .args(["serve", "--connect", hub, "--node-id", node_id, "--name", name, "--config"])
        .arg(config)
        .args(extra)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(serve.stderr.take().unwrap()).lines();
    bounded("serve to start", async {
        while let Some(line) = lines.next_line().await.unwrap() {
            if line.contains("serving spaces") {
                return;
            }
        }
        panic!("serve ended before it served");
    })
    .await;
    tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
    serve
}

/// One HTTP answer.
struct Answer {
    status: u16,
    head: String,
    body: Vec<u8>,
}

impl Answer {
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| panic!("{e}: {}", self.text()))
    }

    fn header(&self, name: &str) -> Option<&str> {
        self.head.lines().find_map(|l| {
            let (n, v) = l.split_once(':')?;
            n.eq_ignore_ascii_case(name).then(|| v.trim())
        })
    }
}

/// A plain HTTP/1.1 request with `headers` (each ending in CRLF), the connection closed
/// after the answer.
async fn http(addr: &str, method: &str, path: &str, headers: &str, body: &[u8]) -> Answer {
    bounded(&format!("{method} {path}"), async {
        let mut socket = tokio::net::TcpStream::connect(addr).await.unwrap();
        let host =
            if headers.to_ascii_lowercase().contains("host:") { String::new() } else { format!("Host: {addr}\r\n") };
        let head = format!(
            "{method} {path} HTTP/1.1\r\n{host}{headers}Content-Length: {}\r\nConnection: close\r\n\r\n",
            body.len()
        );
        socket.write_all(head.as_bytes()).await.unwrap();
        socket.write_all(body).await.unwrap();
        let mut all = Vec::new();
        // The server may close before it has read a body it refused: what it sent is kept.
        let _ = socket.read_to_end(&mut all).await;
        let split = all.windows(4).position(|w| w == b"\r\n\r\n").expect("no HTTP head");
        let head = String::from_utf8_lossy(&all[..split]).into_owned();
        let mut body = all[split + 4..].to_vec();
        let status = head.split_whitespace().nth(1).unwrap().parse().unwrap();
        if head.to_ascii_lowercase().contains("transfer-encoding: chunked") {
            body = dechunk(&body);
        }
        Answer { status, head, body }
    })
    .await
}

fn dechunk(mut data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    for _ in 0..100_000 {
        let Some(end) = data.windows(2).position(|w| w == b"\r\n") else { break };
        let size = usize::from_str_radix(String::from_utf8_lossy(&data[..end]).trim(), 16).unwrap_or(0);
        if size == 0 {
            break;
        }
        out.extend_from_slice(&data[end + 2..end + 2 + size]);
        data = &data[end + 2 + size + 2..];
    }
    out
}

/// Every key of SERVER's CDI that has a value, from `config show --json`.
async fn cli_keys(layout: &Layout) -> Vec<String> {
    let (status, out, err) = layout.cli(&["config", "show", SERVER, "--json"]).await;
    assert_eq!(status, 0, "{err}");
    let shown: Value = serde_json::from_str(&out).unwrap();
    let mut keys = Vec::new();
    fn walk(node: &Value, keys: &mut Vec<String>) {
        match node["children"].as_array() {
            Some(children) => children.iter().for_each(|c| walk(c, keys)),
            None if !node["value"].is_null() => keys.push(node["key"].as_str().unwrap().to_string()),
            None => {}
        }
    }
    shown["segments"].as_array().unwrap().iter().for_each(|s| walk(s, &mut keys));
    assert!(keys.len() > 5, "{keys:?}");
    keys
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_api_writes_verified_backs_up_as_the_cli_and_plans_a_restore() {
    let layout = Layout::start("ui-api", &[]).await;
    assert_eq!(layout.token, None, "no token on the loopback");
    let path = format!("/api/nodes/{SERVER}");

    // The page and its files are served, with the headers that keep it in its own frame.
    let page = http(&layout.addr, "GET", "/", "", b"").await;
    assert_eq!(page.status, 200);
    assert!(page.text().contains("app.js"));
    assert_eq!(page.header("x-frame-options"), Some("DENY"));
    assert!(page.header("content-security-policy").unwrap().contains("default-src 'self'"));

    // The node is found (the first discovery may still run: Refresh waits for its own).
    let nodes = layout.ok("POST", "/api/nodes/refresh", &Value::Null).await;
    let server = nodes["nodes"].as_array().unwrap().iter().find(|n| n["node_id"] == SERVER).cloned();
    let server = server.unwrap_or_else(|| panic!("{SERVER} is not in {nodes}"));
    assert_eq!(server["snip"]["user_name"], "Yard");
    assert!(server["protocols"].as_array().unwrap().iter().any(|p| p == "MemoryConfiguration"), "{server}");

    // The configuration, with every entry the CLI shows.
    let shown = layout.ok("GET", &format!("{path}/config"), &Value::Null).await;
    let (_, cli_out, _) = layout.cli(&["config", "show", SERVER, "--json"]).await;
    let cli: Value = serde_json::from_str(&cli_out).unwrap();
    assert_eq!(shown["segments"], cli["segments"], "the page's tree is `config show`'s");

    // A Save: two changes, written, read back by the CLI.
    let changes = json!({ "changes": [
        { "key": "Configuration.Label", "value": "Branch" },
        { "key": "Configuration.Mode", "value": "Test" },
        { "key": "User identification.User name", "value": "Yard" },
    ] });
    let saved = layout.ok("POST", &format!("{path}/config"), &changes).await;
    assert_eq!(saved["written"], json!(["Configuration.Label", "Configuration.Mode"]), "only what differs");
    assert_eq!(layout.get("Configuration.Label").await, "Branch");
    assert_eq!(layout.get("Configuration.Mode").await, "2");
    assert_eq!(&std::fs::read(&layout.config).unwrap()[..7], b"Branch\0");

    // A bad value writes nothing, not even the good one beside it, in `config set`'s words.
    let bad = json!({ "changes": [
        { "key": "Configuration.Label", "value": "Other" },
        { "key": "Configuration.Delay (ms)", "value": "5000" },
    ] });
    let answer = layout.page("POST", &format!("{path}/config"), bad.to_string().as_bytes()).await;
    assert_eq!(answer.status, 400, "{}", answer.text());
    let (status, _, cli_err) = layout.cli(&["config", "set", SERVER, "Configuration.Delay (ms)", "5000"]).await;
    assert_eq!(status, 2);
    let error = answer.json()["error"].as_str().unwrap().to_string();
    assert!(cli_err.contains(&error), "the page says {error:?}, the CLI {cli_err:?}");
    assert_eq!(layout.get("Configuration.Label").await, "Branch");
    let unknown = json!({ "changes": [{ "key": "No such key", "value": "1" }] });
    let answer = layout.page("POST", &format!("{path}/config"), unknown.to_string().as_bytes()).await;
    assert_eq!(answer.status, 400);
    assert!(answer.json()["error"].as_str().unwrap().contains("the CDI has no entry No such key"));

    // The backup is `config backup`'s, byte for byte.
    let backup = layout.page("GET", &format!("{path}/backup"), b"").await;
    assert_eq!(backup.status, 200);
    assert!(backup.header("content-disposition").unwrap().starts_with("attachment"));
    let (status, cli_backup, _) = layout.cli(&["config", "backup", SERVER]).await;
    assert_eq!(status, 0);
    assert_eq!(backup.text(), cli_backup);
    assert!(cli_backup.contains("Configuration.Label=Branch\n"));

    // A restore: its plan first (nothing written), then the writes.
    let edited = cli_backup.replace("Configuration.Label=Branch", "Configuration.Label=Spur") + "Gone.Key=1\n";
    let plan = layout.page("POST", &format!("{path}/restore"), edited.as_bytes()).await;
    assert_eq!(plan.status, 200, "{}", plan.text());
    let plan = plan.json();
    assert_eq!(plan["writes"], json!([{ "key": "Configuration.Label", "old": "Branch", "new": "Spur" }]));
    assert_eq!(plan["unknown_keys"], json!(["Gone.Key"]));
    assert_eq!(plan["applied"], false);
    assert_eq!(layout.get("Configuration.Label").await, "Branch", "a plan writes nothing");
    let applied = layout.page("POST", &format!("{path}/restore?apply=true"), edited.as_bytes()).await;
    assert_eq!(applied.status, 200, "{}", applied.text());
    assert_eq!(layout.get("Configuration.Label").await, "Spur");
    let twice = "Configuration.Mode=1\nConfiguration.Mode=2\n";
    let answer = layout.page("POST", &format!("{path}/restore"), twice.as_bytes()).await;
    assert_eq!(answer.status, 400);
    assert!(answer.json()["error"].as_str().unwrap().contains("a setting given twice"), "{}", answer.text());

    // A new name: the table shows it.
    let renamed = json!({ "changes": [{ "key": "User identification.User name", "value": "Junction" }] });
    layout.ok("POST", &format!("{path}/config"), &renamed).await;
    let mut name = Value::Null;
    for _ in 0..100 {
        let state = layout.ok("GET", "/api/state", &Value::Null).await;
        let nodes = state["nodes"].as_array().unwrap().clone();
        name = nodes.iter().find(|n| n["node_id"] == SERVER).map_or(Value::Null, |n| n["snip"]["user_name"].clone());
        if name == "Junction" {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    assert_eq!(name, "Junction");

    // Update Complete and a factory reset that is not confirmed.
    let done = layout.ok("POST", &format!("{path}/command/update-complete"), &Value::Null).await;
    assert!(done["message"].as_str().unwrap().contains("accepted Update Complete"));
    let answer = layout.page("POST", &format!("{path}/command/factory-reset"), b"{}").await;
    assert_eq!(answer.status, 400);
    assert!(answer.json()["error"].as_str().unwrap().starts_with("nothing sent"));
    assert_eq!(layout.get("Configuration.Label").await, "Spur");
    let done = layout.ok("POST", &format!("{path}/command/factory-reset"), &json!({ "yes": true })).await;
    assert!(done["message"].as_str().unwrap().contains("accepted the factory reset"), "{done}");

    // What it produces, by Identify Events.
    let events = layout.ok("POST", &format!("{path}/events"), &Value::Null).await;
    let produced: Vec<&Value> =
        events["identified"].as_array().unwrap().iter().filter(|e| e["role"] == "producer").collect();
    assert_eq!(produced.len(), 1, "{events}");
    assert_eq!((&produced[0]["node"], &produced[0]["event"]), (&json!(SERVER), &json!(PRODUCED)));

    // A node that does not answer: the CLI's words.
    let answer = layout.page("GET", &format!("/api/nodes/{NOBODY}/config"), b"").await;
    assert_eq!(answer.status, 504, "{}", answer.text());
    let (status, _, cli_err) = layout.cli(&["config", "show", NOBODY]).await;
    assert_eq!(status, 5);
    let error = answer.json()["error"].as_str().unwrap().to_string();
    assert!(cli_err.contains(&error), "the page says {error:?}, the CLI {cli_err:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_api_refuses_what_another_site_or_a_bad_request_could_send() {
    let layout = Layout::start("ui-refuse", &[]).await;
    let path = format!("/api/nodes/{SERVER}/config");
    let change = json!({ "changes": [{ "key": "Configuration.Label", "value": "Evil" }] }).to_string();
    let body = change.as_bytes();
    // Without the page's header (a form of another site), from another origin, for another
    // host name (DNS rebinding): refused before anything is looked at.
    let bare = http(&layout.addr, "POST", &path, "Content-Type: text/plain\r\n", body).await;
    assert_eq!(bare.status, 403, "{}", bare.text());
    let foreign = http(&layout.addr, "POST", &path, "X-LCC-UI: 1\r\nOrigin: http://evil.example\r\n", body).await;
    assert_eq!(foreign.status, 403, "{}", foreign.text());
    assert!(foreign.json()["error"].as_str().unwrap().contains("another origin"));
    let rebound = http(&layout.addr, "GET", "/api/state", "Host: evil.example:80\r\n", b"").await;
    assert_eq!(rebound.status, 403);
    let same_origin = format!("X-LCC-UI: 1\r\nOrigin: {}\r\n", layout.base);
    let cancel = http(&layout.addr, "POST", "/api/cancel", &same_origin, b"").await;
    assert_eq!(cancel.status, 200, "the page's own origin is served: {}", cancel.text());
    assert_eq!(std::fs::read(&layout.config).unwrap(), vec![0; 256], "nothing written");

    // Bad input: typed 4xx answers, never a crash.
    for (method, path, body, status) in [
        ("GET", "/api/nodes/05.01/config".to_string(), "", 400),
        ("GET", "/api/nodes/00.00.00.00.00.00/config".to_string(), "", 400),
        ("POST", path.clone(), "{not json", 400),
        ("POST", path.clone(), "{\"changes\": 3}", 400),
        ("POST", format!("/api/nodes/{SERVER}/command/format-disk"), "", 404),
        ("POST", "/api/events/send".to_string(), "{\"event\": \"05.01\"}", 400),
        ("POST", "/api/events/send".to_string(), "{\"event\": \"05.01.01.01.22.00.00.01\", \"payload\": \"xyz\"}", 400),
        ("GET", "/no/such/page".to_string(), "", 404),
        ("GET", "/../../etc/passwd".to_string(), "", 404),
    ] {
        let answer = layout.page(method, &path, body.as_bytes()).await;
        assert_eq!(answer.status, status, "{method} {path} {body}: {}", answer.text());
        assert!(answer.json()["error"].is_string(), "{}", answer.text());
    }
    let huge = vec![b'x'; 5 * 1024 * 1024];
    let answer = layout.page("POST", &format!("/api/nodes/{SERVER}/restore"), &huge).await;
    assert_eq!(answer.status, 413, "a body past the bound is refused unread");
    // The process still serves.
    assert_eq!(layout.page("GET", "/api/state", b"").await.status, 200);
    assert_eq!(std::fs::read(&layout.config).unwrap(), vec![0; 256], "nothing written");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_a_token_every_api_request_needs_it() {
    let layout = Layout::start("ui-token", &["--token"]).await;
    let token = layout.token.clone().expect("--token prints a token");
    assert_eq!(token.len(), 32);
    // The page's files need none (they hold nothing); the API does.
    assert_eq!(http(&layout.addr, "GET", "/", "", b"").await.status, 200);
    for (method, path, headers) in [
        ("GET", "/api/state".to_string(), String::new()),
        ("GET", "/api/state?token=wrong".to_string(), String::new()),
        ("POST", "/api/cancel".to_string(), "X-LCC-UI: 1\r\n".to_string()),
        ("POST", format!("/api/cancel?token={token}"), "X-LCC-UI: 1\r\n".to_string()),
        ("POST", format!("/api/nodes/{SERVER}/command/reboot"), format!("X-LCC-UI: {}x\r\n", token)),
    ] {
        let answer = http(&layout.addr, method, &path, &headers, b"").await;
        assert_eq!(answer.status, 403, "{method} {path} {headers}: {}", answer.text());
        assert!(answer.json()["error"].as_str().unwrap().contains("token"), "{}", answer.text());
    }
    assert_eq!(http(&layout.addr, "GET", &format!("/api/state?token={token}"), "", b"").await.status, 200);
    let post = http(&layout.addr, "POST", "/api/cancel", &format!("X-LCC-UI: {token}\r\n"), b"").await;
    assert_eq!(post.status, 200, "{}", post.text());
}

// ---- the browser ----

/// A headless Chromium, driven by the DevTools protocol over its WebSocket; one page.
struct Browser {
    _child: Child,
    socket: tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>,
    session: String,
    next: u64,
}

/// The browser: $LCC_UI_CHROMIUM, else `chromium` (Debian) or `chromium-browser` on PATH.
fn chromium() -> Option<PathBuf> {
    if let Some(path) = std::env::var_os("LCC_UI_CHROMIUM") {
        return Some(PathBuf::from(path));
    }
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .flat_map(|dir| ["chromium", "chromium-browser"].map(|name| dir.join(name)))
        .find(|candidate| candidate.is_file())
}

impl Browser {
    async fn launch(program: &Path, dir: &Path) -> Browser {
        let mut child = Command::new(program)
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--no-first-run",
                "--disable-extensions",
                "--remote-debugging-address=127.0.0.1",
                "--remote-debugging-port=0",
                "--window-size=1000,800",
            ])
            .arg(format!("--user-data-dir={}", dir.join("profile").display()))
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", program.display()));
        let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
        let url = bounded("Chromium's DevTools address", async {
            while let Some(line) = lines.next_line().await.unwrap() {
                if let Some(at) = line.find("ws://") {
                    return line[at..].trim().to_string();
                }
            }
            panic!("Chromium ended before it listened for DevTools");
        })
        .await;
        tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
        let (socket, _) =
            bounded("the DevTools connection", tokio_tungstenite::connect_async(url.as_str())).await.unwrap();
        let mut browser = Browser { _child: child, socket, session: String::new(), next: 1 };
        let target = browser.call("Target.createTarget", json!({ "url": "about:blank" }), false).await;
        let target = target["targetId"].as_str().unwrap().to_string();
        let attached =
            browser.call("Target.attachToTarget", json!({ "targetId": target, "flatten": true }), false).await;
        browser.session = attached["sessionId"].as_str().unwrap().to_string();
        browser.call("Page.enable", json!({}), true).await;
        browser.call("Runtime.enable", json!({}), true).await;
        browser
    }

    /// One DevTools command (to the page's session when `page`); its result.
    async fn call(&mut self, method: &str, params: Value, page: bool) -> Value {
        let id = self.next;
        self.next += 1;
        let mut request = json!({ "id": id, "method": method, "params": params });
        if page {
            request["sessionId"] = json!(self.session);
        }
        bounded(method, async {
            self.socket.send(Message::text(request.to_string())).await.unwrap();
            while let Some(message) = self.socket.next().await {
                let Message::Text(text) = message.unwrap() else { continue };
                let answer: Value = serde_json::from_str(text.as_str()).unwrap();
                if answer["id"] == json!(id) {
                    if !answer["error"].is_null() {
                        panic!("{method}: {}", answer["error"]);
                    }
                    return answer["result"].clone();
                }
            }
            panic!("the DevTools connection closed during {method}");
        })
        .await
    }

    /// Evaluates `expression` in the page (a promise is awaited); its value.
    async fn eval(&mut self, expression: &str) -> Value {
        let params = json!({ "expression": expression, "awaitPromise": true, "returnByValue": true });
        let result = self.call("Runtime.evaluate", params, true).await;
        if let Some(details) = result.get("exceptionDetails") {
            panic!("{expression}: {}", details["exception"]["description"].as_str().unwrap_or(&details.to_string()));
        }
        result["result"]["value"].clone()
    }

    /// Waits until `condition` (an expression) is truthy in the page, checking every 50 ms,
    /// at most 1200 times (a minute); its value, or a panic naming `what`.
    async fn wait_for(&mut self, what: &str, condition: &str) -> Value {
        let expression = format!(
            "new Promise((resolve, reject) => {{ let tries = 0; const check = () => {{ \
               let value; try {{ value = ({condition}); }} catch (e) {{ value = null; }} \
               if (value) return resolve(value); \
               if (++tries >= 1200) return reject(new Error('never: ' + {what:?} + '; the message: ' + \
                 (document.getElementById('message') || {{}}).textContent + '; the page: ' + location.hash + ' ' + \
                 (document.getElementById('view') || {{}}).textContent.slice(0, 300))); \
               setTimeout(check, 50); }}; check(); }})"
        );
        self.eval(&expression).await
    }

    async fn navigate(&mut self, url: &str) {
        self.call("Page.navigate", json!({ "url": url }), true).await;
    }

    /// Puts `file` into the file input `selector`, as a person choosing it would.
    async fn choose_file(&mut self, selector: &str, file: &Path) {
        let document = self.call("DOM.getDocument", json!({}), true).await;
        let root = document["root"]["nodeId"].clone();
        let found = self.call("DOM.querySelector", json!({ "nodeId": root, "selector": selector }), true).await;
        let params = json!({ "files": [file.display().to_string()], "nodeId": found["nodeId"] });
        self.call("DOM.setFileInputFiles", params, true).await;
    }

    /// A PNG of the page as it is, into `dir/name` when screenshots are asked for.
    async fn screenshot(&mut self, dir: Option<&Path>, name: &str) {
        let Some(dir) = dir else { return };
        let shot = self.call("Page.captureScreenshot", json!({ "format": "png" }), true).await;
        let data = shot["data"].as_str().unwrap();
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join(name), base64_decode(data)).unwrap();
    }
}

/// Standard base64 (DevTools' screenshots).
fn base64_decode(text: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'a'..=b'z' => Some(c - b'a' + 26),
        b'0'..=b'9' => Some(c - b'0' + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    };
    let digits: Vec<u8> = text.bytes().filter_map(value).collect();
    let mut out = Vec::with_capacity(digits.len() * 3 / 4);
    for chunk in digits.chunks(4) {
        let n = chunk.iter().enumerate().fold(0u32, |n, (i, d)| n | (u32::from(*d) << (18 - 6 * i)));
        let bytes = n.to_be_bytes();
        out.extend_from_slice(&bytes[1..chunk.len()]);
    }
    out
}

#[test]
fn base64_decodes() {
    assert_eq!(base64_decode("aGVsbG8="), b"hello");
    assert_eq!(base64_decode("aGVsbG8h"), b"hello!");
}

/// A node that answers `ui`'s first discovery two seconds late (a busy machine, a slow bus:
/// the discovery stops a second after the last answer) is in the table all the same: the
/// monitor heard its Verified Node ID. The node is logged in by hand as 05.01.01.01.22.F0
/// (alias 0x5A5) before `ui` starts, so its Initialization Complete is not heard.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_that_answers_the_first_discovery_late_is_in_the_table() {
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let (read, mut write) = tokio::net::TcpStream::connect(&addr).await.unwrap().into_split();
    let login = ":X170505A5N;:X161015A5N;:X150125A5N;:X142F05A5N;:X107005A5N;:X107015A5N0501010122F0;";
    write.write_all(format!("{login}:X191005A5N0501010122F0;\n").as_bytes()).await.unwrap();
    let late = tokio::spawn(async move {
        let mut lines = BufReader::new(read).lines();
        while let Ok(Some(line)) = lines.next_line().await {
            if line.starts_with(":X19490") {
                tokio::time::sleep(std::time::Duration::from_secs(2)).await;
                write.write_all(b":X191705A5N0501010122F0;\n").await.unwrap();
                // Stays on the bus (SNIP and PIP go unanswered) until the test ends.
                while let Ok(Some(_)) = lines.next_line().await {}
                return true;
            }
        }
        false
    });
    let (_ui, listen, _) = start_ui(&addr, &[]).await;
    let table = bounded("the late node in the table", async {
        loop {
            let state = http(&listen, "GET", "/api/state", "X-LCC-UI: 1\r\n", b"").await.json();
            if state["nodes"].as_array().is_some_and(|nodes| !nodes.is_empty()) {
                return state["nodes"].clone();
            }
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        }
    })
    .await;
    assert_eq!(table[0]["node_id"], "05.01.01.01.22.F0", "{table}");
    assert_eq!(table[0]["alias"], "5A5", "{table}");
    assert!(!late.is_finished(), "the node left the bus");
}

/// The browser, or None when there is none and LCC_UI_BROWSER_TEST=skip says that is fine.
fn browser_or_skip() -> Option<PathBuf> {
    if let Some(program) = chromium() {
        return Some(program);
    }
    if std::env::var("LCC_UI_BROWSER_TEST").as_deref() == Ok("skip") {
        eprintln!("no chromium, and LCC_UI_BROWSER_TEST=skip: the browser test is skipped");
        return None;
    }
    panic!(
        "the browser test needs chromium (apt-get install chromium, or LCC_UI_CHROMIUM=PATH); \
         LCC_UI_BROWSER_TEST=skip skips it"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn in_a_browser_the_table_the_configuration_a_save_a_restore_and_the_monitor() {
    let Some(program) = browser_or_skip() else { return };
    let shots = std::env::var_os("LCC_UI_SCREENSHOTS").map(PathBuf::from);
    let shots = shots.as_deref();
    let layout = Layout::start("ui-browser", &[]).await;
    let mut browser = Browser::launch(&program, &layout.dir).await;

    // The table: the node, with its name.
    browser.navigate(&format!("{}/", layout.base)).await;
    let row = format!("document.querySelector('tr[data-node=\"{SERVER}\"]')");
    let text = browser.wait_for("the node in the table", &format!("{row} && {row}.textContent")).await;
    assert!(text.as_str().unwrap().contains("Yard"), "{text}");
    browser.screenshot(shots, "ui-nodes.png").await;

    // Its page, then Configure: every variable of serve's CDI, each as its control.
    browser.eval(&format!("{row}.click()")).await;
    browser.wait_for("the node's page", "document.getElementById('configure')").await;
    browser.eval("document.getElementById('configure').click()").await;
    let label = "document.querySelector('[data-key=\"Configuration.Label\"]')";
    browser.wait_for("the configuration page", label).await;
    let keys = browser.eval("[...document.querySelectorAll('[data-key]')].map((e) => e.dataset.key)").await;
    let keys: Vec<String> = serde_json::from_value(keys).unwrap();
    assert_eq!(keys, cli_keys(&layout).await, "the page shows every setting `config show` shows");
    let mode = "document.querySelector('[data-key=\"Configuration.Mode\"]')";
    assert_eq!(browser.eval(&format!("{mode}.tagName")).await, "SELECT", "a map is a select");
    assert_eq!(browser.eval(&format!("{label}.maxLength")).await, 31, "a string's size, less its NUL");
    browser.wait_for("the read to end", "document.getElementById('job').hidden").await;
    browser.screenshot(shots, "ui-configure.png").await;
    if shots.is_some() {
        // The same page on a phone's screen.
        let phone = json!({ "width": 390, "height": 844, "deviceScaleFactor": 2, "mobile": true });
        browser.call("Emulation.setDeviceMetricsOverride", phone, true).await;
        browser.screenshot(shots, "ui-configure-phone.png").await;
        browser.call("Emulation.clearDeviceMetricsOverride", json!({}), true).await;
    }

    // A change, marked; Save; the CLI reads it back.
    browser
        .eval(&format!("{label}.value = 'Branch'; {label}.dispatchEvent(new Event('input')); {label}.className"))
        .await;
    assert_eq!(browser.eval(&format!("{label}.classList.contains('changed')")).await, true);
    assert_eq!(browser.eval("document.getElementById('save').textContent").await, "Save 1 change(s)");
    browser.eval("document.getElementById('save').click()").await;
    let message = "document.getElementById('message-text')";
    let said = browser
        .wait_for("the save", &format!("{message} && {message}.textContent.includes('saved') && {message}.textContent"))
        .await;
    assert!(said.as_str().unwrap().contains("1 setting(s) written and read back"), "{said}");
    assert_eq!(browser.eval(&format!("{label}.classList.contains('changed')")).await, false);
    assert_eq!(layout.get("Configuration.Label").await, "Branch");

    // The backup link gives `config backup`'s bytes.
    let node_page = format!("{}/#/node/{SERVER}", layout.base);
    browser.navigate(&node_page).await;
    browser.wait_for("the node's page", "document.getElementById('backup')").await;
    let downloaded = browser.eval("fetch(document.getElementById('backup').href).then((r) => r.text())").await;
    let (_, cli_backup, _) = layout.cli(&["config", "backup", SERVER]).await;
    assert_eq!(downloaded.as_str().unwrap(), cli_backup);

    // A restore uploaded shows its plan, then writes it.
    let file = layout.dir.join("edited.txt");
    std::fs::write(&file, cli_backup.replace("Configuration.Label=Branch", "Configuration.Label=Spur")).unwrap();
    browser.choose_file("#restore-file", &file).await;
    browser.eval("document.getElementById('restore-show').click()").await;
    let plan = "document.getElementById('restore-plan')";
    let shown = browser.wait_for("the plan", &format!("{plan}.textContent.includes('→') && {plan}.textContent")).await;
    assert!(shown.as_str().unwrap().contains("Configuration.Label: Branch → Spur"), "{shown}");
    assert_eq!(layout.get("Configuration.Label").await, "Branch", "the plan wrote nothing");
    browser.eval("document.getElementById('restore-apply').click()").await;
    browser.wait_for("the restore", &format!("{message} && {message}.textContent.startsWith('restored')")).await;
    assert_eq!(layout.get("Configuration.Label").await, "Spur");

    // A firmware image uploaded from the page (the confirmation answered yes), with its
    // outcome in words; serve saves it.
    let image = layout.dir.join("image.bin");
    std::fs::write(&image, (0..3000u32).map(|i| (i % 241) as u8).collect::<Vec<u8>>()).unwrap();
    browser.eval("window.confirm = () => true").await;
    browser.choose_file("#firmware-file", &image).await;
    browser.eval("document.getElementById('firmware-upload').click()").await;
    let upgraded = browser
        .wait_for(
            "the upgrade",
            &format!("{message} && {message}.textContent.startsWith('upgraded') && {message}.textContent"),
        )
        .await;
    assert!(upgraded.as_str().unwrap().contains("with 3000 bytes"), "{upgraded}");
    let saved = layout.dir.join(format!("firmware-{}.bin", SERVER.replace('.', "")));
    assert_eq!(std::fs::read(saved).unwrap(), std::fs::read(&image).unwrap());
    browser.eval("document.getElementById('factory-reset').click()").await;
    browser
        .wait_for(
            "the factory reset",
            &format!("{message} && {message}.textContent.includes('accepted the factory reset')"),
        )
        .await;

    // The monitor and the events page show a report sent by `events send`.
    browser.navigate(&format!("{}/#/monitor", layout.base)).await;
    browser.wait_for("the monitor", "document.getElementById('lines')").await;
    let (status, _, err) = layout.cli(&["events", "send", "05.01.01.01.22.00.00.2A"]).await;
    assert_eq!(status, 0, "{err}");
    let lines = "document.getElementById('lines').textContent";
    let seen = browser
        .wait_for("the report in the monitor", &format!("{lines}.includes('05.01.01.01.22.00.00.2A') && {lines}"))
        .await;
    assert!(seen.as_str().unwrap().contains("Producer/Consumer Event Report"), "{seen}");
    browser.eval("document.getElementById('filter-kind').value = 'snip'; document.getElementById('filter-kind').dispatchEvent(new Event('change'))").await;
    assert_eq!(browser.eval(&format!("{lines}.includes('05.01.01.01.22.00.00.2A')")).await, false, "filtered out");
    let trace = browser.eval("fetch(document.getElementById('trace').href).then((r) => r.text())").await;
    let trace_file = layout.dir.join("trace.txt");
    std::fs::write(&trace_file, trace.as_str().unwrap()).unwrap();
    let decoded = Command::new(BIN).arg("monitor").arg("--from").arg(&trace_file).kill_on_drop(true).output();
    let decoded = bounded("monitor --from", decoded).await.unwrap();
    let (status, err) = (decoded.status.code().unwrap_or(-1), String::from_utf8_lossy(&decoded.stderr));
    let decoded = String::from_utf8_lossy(&decoded.stdout);
    assert_eq!(status, 0, "{err}");
    assert!(decoded.contains("05.01.01.01.22.00.00.2A"), "the trace `monitor --from` reads: {decoded}");
    browser.navigate(&format!("{}/#/events", layout.base)).await;
    let reports = "document.getElementById('reports')";
    browser
        .wait_for(
            "the report on the events page",
            &format!("{reports} && {reports}.textContent.includes('05.01.01.01.22.00.00.2A')"),
        )
        .await;

    // A node that does not answer: the page says so in the CLI's words.
    browser.navigate(&format!("{}/#/node/{NOBODY}/config", layout.base)).await;
    let error = "document.getElementById('config-error')";
    let said = browser.wait_for("the error", &format!("{error} && {error}.textContent")).await;
    let (status, _, cli_err) = layout.cli(&["config", "show", NOBODY]).await;
    assert_eq!(status, 5);
    assert!(cli_err.contains(said.as_str().unwrap()), "the page says {said}, the CLI {cli_err:?}");

    // The clock pane: a generator's time, and Stop confirmed by it.
    let _generator = Command::new(BIN)
        .args(["clock", "--connect", &layout.hub, "--rate", "4", "--time", "06:00", "--date", "1956-07-04"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    browser.navigate(&format!("{}/#/clock", layout.base)).await;
    let time = "document.getElementById('clock-time').textContent";
    browser.wait_for("the generator's time", &format!("{time}.startsWith('1956-07-04 06:')")).await;
    let status = "document.getElementById('clock-status').textContent";
    assert_eq!(browser.eval(status).await, "default-fast: running at 4x");
    browser.eval("document.getElementById('clock-stop').click()").await;
    let stopped = browser
        .wait_for(
            "the stop confirmed",
            &format!("{message} && {message}.textContent.includes('stopped') && {message}.textContent"),
        )
        .await;
    assert!(stopped.as_str().unwrap().starts_with("default-fast stopped (generator"), "{stopped}");

    // A node that joins appears in the open table by itself (its Initialization Complete).
    browser.navigate(&format!("{}/#/", layout.base)).await;
    browser.wait_for("the table", &row).await;
    let config = layout.dir.join("second.bin");
    std::fs::write(&config, vec![0; 256]).unwrap();
    let _second = serve(&layout.dir, &layout.hub, "05.01.01.01.22.E3", "Spur", &config, &[]).await;
    let second = "document.querySelector('tr[data-node=\"05.01.01.01.22.E3\"]')";
    let text = browser
        .wait_for(
            "the joined node",
            &format!("{second} && {second}.textContent.includes('Spur') && {second}.textContent"),
        )
        .await;
    assert!(text.as_str().unwrap().contains("Spur"), "{text}");
}

/// The node of `serve` with a 16 KiB configuration (16 000 settings and more): its page
/// renders, and a Save of 100 changes writes them all. The figures are printed (a test that
/// fails on time would fail on a busy machine): the time from the navigation to the page
/// drawn (the CDI and the values read over the bus included), and to 100 changes saved.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn in_a_browser_a_16_kib_configuration_renders_and_saves_100_changes() {
    let Some(program) = browser_or_skip() else { return };
    let layout = Layout::sized("ui-16k", 16 * 1024, &[]).await;
    let mut browser = Browser::launch(&program, &layout.dir).await;
    let started = std::time::Instant::now();
    browser.navigate(&format!("{}/#/node/{SERVER}/config", layout.base)).await;
    let config = "document.getElementById('config')";
    let entries = browser
        .wait_for(
            "the page drawn",
            &format!("{config} && {config}.dataset.shownMs && Number({config}.dataset.entries)"),
        )
        .await;
    let drawn = started.elapsed();
    let shown_ms = browser.eval(&format!("{config}.dataset.shownMs")).await;
    let entries = entries.as_u64().unwrap();
    assert!(entries > 16_000, "{entries} settings");
    let spare = "[...document.querySelectorAll('[data-key*=\"Spare\"]')].slice(0, 100)";
    let set = format!(
        "{spare}.forEach((i) => {{ i.value = '7'; i.dispatchEvent(new Event('input')); }}); document.getElementById('save').textContent"
    );
    assert_eq!(browser.eval(&set).await, "Save 100 change(s)");
    let saving = std::time::Instant::now();
    browser.eval("document.getElementById('save').click()").await;
    let message = "document.getElementById('message-text')";
    let said = browser
        .wait_for("the save", &format!("{message} && {message}.textContent.includes('saved') && {message}.textContent"))
        .await;
    let saved = saving.elapsed();
    assert!(said.as_str().unwrap().contains("100 setting(s) written and read back"), "{said}");
    // The spare bytes follow the 171 bytes of settings of serve's CDI.
    let held = std::fs::read(&layout.config).unwrap();
    assert!(held[171..271].iter().all(|b| *b == 7), "every change is in serve's file");
    assert!(held[271..].iter().all(|b| *b == 0) && held[..171].iter().all(|b| *b == 0), "and nothing else");
    eprintln!(
        "16 KiB configuration, {entries} settings: drawn {:.2} s after the navigation (the page: {shown_ms} ms \
         from its request to its paint, the bus read included); 100 changes saved in {:.2} s",
        drawn.as_secs_f64(),
        saved.as_secs_f64()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_firmware_upgrade_goes_through_shows_its_progress_and_is_cancelled_by_cancel() {
    let layout = Layout::start("ui-firmware", &[]).await;
    let path = format!("/api/nodes/{SERVER}/firmware");
    // A small image goes through whole: serve saves it.
    let image: Vec<u8> = (0..5000u32).map(|i| (i * 7 % 251) as u8).collect();
    let done = layout.page("POST", &path, &image).await;
    assert_eq!(done.status, 200, "{}", done.text());
    let message = done.json()["message"].as_str().unwrap().to_string();
    assert!(message.starts_with(&format!("upgraded {SERVER} with 5000 bytes")), "{message}");
    let saved = layout.dir.join(format!("firmware-{}.bin", SERVER.replace('.', "")));
    assert_eq!(std::fs::read(&saved).unwrap(), image);
    assert_eq!(layout.page("POST", &path, b"").await.status, 400, "an empty image is refused");

    // A large one: its progress is shown, a second operation meanwhile is refused, and
    // Cancel stops it in the CLI's words.
    let big: Vec<u8> = (0..8 * 1024 * 1024u32).map(|i| (i % 253) as u8).collect();
    let addr = layout.addr.clone();
    let upload = tokio::spawn(async move { http(&addr, "POST", &path, "X-LCC-UI: 1\r\n", &big).await });
    let mut running = Value::Null;
    for _ in 0..6000 {
        let state = layout.ok("GET", "/api/state", &Value::Null).await;
        if state["job"]["bytes"].as_u64().unwrap_or(0) > 0 {
            running = state["job"].clone();
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    assert_eq!(running["total"], 8 * 1024 * 1024, "the job and its progress: {running}");
    assert!(running["what"].as_str().unwrap().starts_with("upgrading the firmware of"), "{running}");
    let busy = layout.page("GET", &format!("/api/nodes/{SERVER}/config"), b"").await;
    assert_eq!(busy.status, 409, "{}", busy.text());
    assert!(busy.json()["error"].as_str().unwrap().contains("another operation is running"));
    let cancelled = layout.ok("POST", "/api/cancel", &Value::Null).await;
    assert_eq!(cancelled["cancelled"], true);
    let answer = bounded("the cancelled upload", upload).await.unwrap();
    assert_eq!(answer.status, 409, "{}", answer.text());
    let error = answer.json()["error"].as_str().unwrap().to_string();
    assert!(error.starts_with("cancelled; the node was left in firmware upgrade mode"), "{error}");
    assert_eq!(layout.ok("GET", "/api/state", &Value::Null).await["job"], Value::Null, "nothing runs");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ctrl_c_stops_the_page_with_a_page_open() {
    let mut layout = Layout::start("ui-stop", &[]).await;
    // An open page: its live updates stay open until the server goes.
    let mut live = tokio::net::TcpStream::connect(&layout.addr).await.unwrap();
    let request = format!("GET /api/live HTTP/1.1\r\nHost: {}\r\n\r\n", layout.addr);
    live.write_all(request.as_bytes()).await.unwrap();
    let mut head = [0u8; 12];
    bounded("the live updates", live.read_exact(&mut head)).await.unwrap();
    assert_eq!(&head, b"HTTP/1.1 200");
    common::interrupt(&layout.ui).await;
    let status = bounded("ui's exit", layout.ui.wait()).await.unwrap();
    assert_eq!(status.code(), Some(130));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_clock_pane_follows_and_drives_the_generator() {
    let layout = Layout::start("ui-clock", &[]).await;
    // No generator yet: a set is not confirmed, in the words of `clock start`.
    let answer = layout.page("POST", "/api/clock", b"\"start\"").await;
    assert_eq!(answer.status, 504, "{}", answer.text());
    assert!(answer.json()["error"].as_str().unwrap().starts_with("no generator of"), "{}", answer.text());
    assert_eq!(layout.page("POST", "/api/clock", b"{\"rate\": \"fast\"}").await.status, 400);
    assert_eq!(layout.page("POST", "/api/clock", b"{\"time\": \"25:00\"}").await.status, 400);
    assert_eq!(layout.page("POST", "/api/clock", b"\"explode\"").await.status, 400);

    let _generator = Command::new(BIN)
        .args(["clock", "--connect", &layout.hub, "--rate", "4", "--time", "06:00", "--date", "1956-07-04"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    // Stop: the generator's synchronization sequence confirms it, and the pane shows it.
    let mut stopped = Value::Null;
    for _ in 0..60 {
        let answer = layout.page("POST", "/api/clock", b"\"stop\"").await;
        if answer.status == 200 {
            stopped = answer.json();
            break;
        }
        // The generator is still logging in: no confirmation came.
        assert_eq!(answer.status, 504, "{}", answer.text());
    }
    assert!(stopped["message"].as_str().unwrap().contains("stopped"), "{stopped}");
    let mut clock = layout.ok("GET", "/api/clock", &Value::Null).await;
    assert_eq!(clock["synchronized"], true, "{clock}");
    assert!(clock["time"].as_str().unwrap().starts_with("1956-07-04 0"), "{clock}");
    let set = layout.ok("POST", "/api/clock", &json!({ "time": "08:30" })).await;
    assert!(set["message"].as_str().unwrap().contains("time 08:30"), "{set}");
    let set = layout.ok("POST", "/api/clock", &json!({ "rate": "8" })).await;
    assert!(set["message"].as_str().unwrap().contains("rate 8"), "{set}");
    for _ in 0..100 {
        clock = layout.ok("GET", "/api/clock", &Value::Null).await;
        if clock["rate"] == "8" {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    assert!(clock["time"].as_str().unwrap().starts_with("1956-07-04 08:30"), "{clock}");
    assert_eq!(clock["rate"], "8", "{clock}");
}

/// The throttle pane takes a train by its DCC address (as `throttle` does), drives it, and
/// gives it back; `lcc-stream train` says what it got.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_throttle_pane_acquires_drives_and_releases_a_train() {
    let layout = Layout::start("ui-throttle", &[]).await;
    let answer = layout.page("POST", "/api/throttle", b"{\"speed\": 10}").await;
    assert_eq!(answer.status, 400, "nothing held: {}", answer.text());
    assert_eq!(layout.page("POST", "/api/throttle", b"{\"acquire\": {\"address\": 0}}").await.status, 400);
    let mut train = Command::new(BIN)
        .args(["train", "--connect", &layout.hub, "--node-id", "05.01.01.01.22.C7", "--json"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut printed = BufReader::new(train.stdout.take().unwrap()).lines();
    // Once the train has logged in and taken its own address, it answers the search.
    let mut said = BufReader::new(train.stderr.take().unwrap()).lines();
    common::until(&mut said, "DCC 3 as").await;
    let mut acquired = Value::Null;
    for _ in 0..60 {
        let answer = layout.page("POST", "/api/throttle", b"{\"acquire\": {\"address\": 3}}").await;
        if answer.status == 200 {
            acquired = answer.json();
            break;
        }
        // The train is still logging in: nobody answered the search.
        assert_eq!(answer.status, 504, "{}", answer.text());
    }
    assert_eq!(acquired["train"], "05.01.01.01.22.C7", "{acquired}");
    let held = layout.ok("GET", "/api/throttle", &Value::Null).await;
    assert_eq!((held["train"].as_str(), held["address"].as_u64()), (Some("05.01.01.01.22.C7"), Some(3)));
    let mut until = async |needle: &str| {
        bounded(needle, async {
            while let Some(line) = printed.next_line().await.unwrap() {
                if line.contains(needle) {
                    return line;
                }
            }
            panic!("the train ended before {needle}");
        })
        .await
    };
    until("\"controller-assigned\"").await;
    let said = layout.ok("POST", "/api/throttle", &json!({ "speed": -36 })).await;
    assert!(said["message"].as_str().unwrap().ends_with("speed -36 km/h"), "read back from the train: {said}");
    let line = until("\"set_speed\"").await;
    assert!(line.contains("\"set_speed\":-10"), "{line}");
    let said = layout.ok("POST", "/api/throttle", &json!({ "function": { "number": 2, "on": true } })).await;
    assert!(said["message"].as_str().unwrap().ends_with("F2 on"), "read back from the train: {said}");
    let line = until("\"function\"").await;
    assert!(line.contains("\"function\":2") && line.contains("\"value\":1"), "{line}");
    assert_eq!(
        layout.page("POST", "/api/throttle", b"{\"function\": {\"number\": 69, \"on\": true}}").await.status,
        400
    );
    layout.ok("POST", "/api/throttle", &json!("release")).await;
    until("\"controller-released\"").await;
    assert_eq!(layout.ok("GET", "/api/throttle", &Value::Null).await["train"], Value::Null);
}
