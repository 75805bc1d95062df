//! `lcc-stream serve` with `read`, `write` and `firmware`, each a separate process of the
//! built binary, through an in-process hub on 127.0.0.1 (ephemeral port). Every wait is
//! bounded; children are killed when a test ends.

mod common;

use std::path::Path;
use std::process::Stdio;

use common::{BIN, bounded, scratch};
use openlcb_tokio::openlcb_node::{MemoryServer, MemorySpace, RamSpace, SpaceError};
use openlcb_tokio::{Framing, Hub, HubOptions, Node, NodeOptions};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};
use tokio::sync::mpsc;

fn data(len: usize, key: u32) -> Vec<u8> {
    (0..len).map(|i| (i as u32 ^ key).wrapping_mul(2_654_435_761).rotate_right(11) as u8).collect()
}

/// A hub on 127.0.0.1 for one test; its address.
async fn hub() -> (Hub, String) {
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    (hub, addr)
}

/// A `serve` process and its stderr, line by line.
struct Server {
    /// Killed when the test ends.
    child: Child,
    lines: mpsc::UnboundedReceiver<String>,
}

impl Server {
    async fn start(dir: &Path, hub: &str, node_id: &str, extra: &[&str]) -> Server {
        let mut child = Command::new(BIN)
            .current_dir(dir)
            .args(["serve", "--connect", hub, "--node-id", node_id])
            .args(extra)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .unwrap();
        let (tx, lines) = mpsc::unbounded_channel();
        let mut stderr = BufReader::new(child.stderr.take().unwrap()).lines();
        tokio::spawn(async move {
            while let Ok(Some(line)) = stderr.next_line().await {
                let _ = tx.send(line);
            }
        });
        let mut server = Server { child, lines };
        server.wait_for("serving spaces").await;
        server
    }

    /// The next stderr line that contains `needle`.
    async fn wait_for(&mut self, needle: &str) -> String {
        bounded(needle, async {
            while let Some(line) = self.lines.recv().await {
                if line.contains(needle) {
                    return line;
                }
            }
            panic!("serve's stderr ended before a line with {needle:?}");
        })
        .await
    }
}

/// Runs the binary with `args` to its end: exit status and the JSON object it printed.
async fn run(hub: &str, args: &[&str]) -> (i32, serde_json::Value) {
    let output = Command::new(BIN)
        .args(args)
        .args(["--connect", hub, "--json"])
        .stdin(Stdio::null())
        .kill_on_drop(true)
        .output();
    let output = bounded(&args.join(" "), output).await.unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    let json = serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("{args:?}: {e} in {stdout:?}; stderr {}", String::from_utf8_lossy(&output.stderr)));
    (output.status.code().unwrap_or(-1), json)
}

fn path_arg(path: &Path) -> &str {
    path.to_str().unwrap()
}

const SERVER: &str = "05.01.01.01.22.E2";

/// A scratch folder named for `test`, a hub, and `serve` as SERVER with a 256-byte
/// configuration file of zeros: the folder, the hub, its address, the file, the server.
async fn serve_zeros(test: &str) -> (std::path::PathBuf, Hub, String, std::path::PathBuf, Server) {
    let dir = scratch(test);
    let (hub, addr) = hub().await;
    let config = dir.join("config.bin");
    std::fs::write(&config, vec![0; 256]).unwrap();
    let server = Server::start(&dir, &addr, SERVER, &["--config", path_arg(&config)]).await;
    (dir, hub, addr, config, server)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_and_write_the_configuration_by_stream_and_by_datagrams() {
    let dir = scratch("config");
    let (_hub, addr) = hub().await;
    let config = dir.join("config.bin");
    std::fs::write(&config, data(1000, 1)).unwrap();
    let _server = Server::start(&dir, &addr, SERVER, &["--config", path_arg(&config)]).await;

    for (name, extra) in [("by-stream.bin", None), ("by-datagrams.bin", Some("--no-stream"))] {
        let out = dir.join(name);
        let mut args = vec!["read", "--from", SERVER, "--out", path_arg(&out)];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_eq!(status, 0, "{json}");
        assert_eq!(json["bytes"], 1000);
        assert_eq!(json["result"], "ok");
        assert_eq!(std::fs::read(&out).unwrap(), data(1000, 1), "{name}");
        assert!(!dir.join(format!("{name}.part")).exists());
    }

    // Restore other bytes, by stream and by datagrams; the file behind space 0xFD follows.
    for (key, extra) in [(2, None), (3, Some("--no-stream"))] {
        let restore = dir.join(format!("restore-{key}.bin"));
        std::fs::write(&restore, data(1000, key)).unwrap();
        let mut args = vec!["write", path_arg(&restore), "--to", SERVER];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_eq!(status, 0, "{json}");
        assert_eq!(json["bytes"], 1000);
        assert_eq!(std::fs::read(&config).unwrap(), data(1000, key));
        let back = dir.join(format!("back-{key}.bin"));
        let (status, _) = run(&addr, &["read", "--from", SERVER, "--out", path_arg(&back)]).await;
        assert_eq!(status, 0);
        assert_eq!(std::fs::read(&back).unwrap(), data(1000, key));
    }

    // A part of the space.
    let part = dir.join("part.bin");
    let args = ["read", "--from", SERVER, "--address", "0x10", "--length", "100", "--out", path_arg(&part)];
    assert_eq!(run(&addr, &args).await.0, 0);
    assert_eq!(std::fs::read(&part).unwrap(), data(1000, 3)[0x10..0x10 + 100]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn firmware_by_stream_and_by_datagrams_arrives_whole() {
    let dir = scratch("firmware");
    let (_hub, addr) = hub().await;
    let out = dir.join("image.bin");
    let mut server = Server::start(&dir, &addr, SERVER, &["--firmware-out", path_arg(&out), "--force"]).await;
    // 100 000 bytes: not a whole number of windows or of datagrams.
    for (key, extra) in [(4, None), (5, Some("--no-stream"))] {
        let image = dir.join(format!("upgrade-{key}.bin"));
        std::fs::write(&image, data(100_000, key)).unwrap();
        let mut args = vec!["firmware", path_arg(&image), "--to", SERVER];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_eq!(status, 0, "{json}");
        assert_eq!(json["bytes"], 100_000);
        server.wait_for("written to").await;
        assert_eq!(std::fs::read(&out).unwrap(), data(100_000, key), "{extra:?}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_without_streams_is_read_and_upgraded_by_datagrams() {
    let dir = scratch("no-streams");
    let (_hub, addr) = hub().await;
    let mut server = Server::start(&dir, &addr, SERVER, &["--no-streams", "--name", "Yard"]).await;
    let image = dir.join("upgrade.bin");
    std::fs::write(&image, data(5000, 6)).unwrap();
    let (status, json) = run(&addr, &["firmware", path_arg(&image), "--to", SERVER]).await;
    assert_eq!(status, 0, "{json}");
    server.wait_for("written to").await;
    // The default output: firmware-<node id>.bin in serve's folder.
    assert_eq!(std::fs::read(dir.join("firmware-0501010122E2.bin")).unwrap(), data(5000, 6));
    // The whole configuration space (256 bytes in memory) and the ACDI user space.
    let config = dir.join("config.bin");
    let (status, json) = run(&addr, &["read", "--from", SERVER, "--out", path_arg(&config)]).await;
    assert_eq!((status, json["bytes"].as_u64()), (0, Some(256)), "{json}");
    let user = dir.join("user.bin");
    let (status, _) = run(&addr, &["read", "--from", SERVER, "--space", "0xFB", "--out", path_arg(&user)]).await;
    assert_eq!(status, 0);
    assert_eq!(std::fs::read(&user).unwrap()[1..5], *b"Yard");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nothing_is_written_over_an_existing_file() {
    let dir = scratch("overwrite");
    let (_hub, addr) = hub().await;
    // `serve` with a firmware output that exists starts, and its image takes a fresh name.
    let taken = dir.join("taken.bin");
    std::fs::write(&taken, b"keep me").unwrap();
    let mut server = Server::start(&dir, &addr, SERVER, &["--firmware-out", path_arg(&taken)]).await;
    let image = dir.join("upgrade.bin");
    std::fs::write(&image, data(2000, 3)).unwrap();
    assert_eq!(run(&addr, &["firmware", path_arg(&image), "--to", SERVER]).await.0, 0);
    server.wait_for("written to").await;
    assert_eq!(std::fs::read(&taken).unwrap(), b"keep me");
    assert_eq!(std::fs::read(dir.join("taken-1.bin")).unwrap(), data(2000, 3));
    // `read` refuses an output that exists, and leaves no .part behind.
    let (status, json) = run(&addr, &["read", "--from", SERVER, "--out", path_arg(&taken)]).await;
    assert_eq!(status, 8, "{json}");
    assert_eq!(json["result"], "file_error");
    assert_eq!(std::fs::read(&taken).unwrap(), b"keep me");
    assert!(!dir.join("taken.bin.part").exists());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_writes_through_a_fifo_and_never_replaces_it() {
    use std::os::unix::fs::FileTypeExt as _;
    let dir = scratch("fifo");
    let (_hub, addr) = hub().await;
    let _server = Server::start(&dir, &addr, SERVER, &[]).await;
    let fifo = dir.join("fifo");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let reader = {
        let fifo = fifo.clone();
        tokio::task::spawn_blocking(move || std::fs::read(fifo).unwrap())
    };
    let (status, json) =
        run(&addr, &["read", "--from", SERVER, "--length", "100", "--force", "--out", path_arg(&fifo)]).await;
    assert_eq!(status, 0, "{json}");
    let through = bounded("the FIFO's reader", reader).await.unwrap();
    assert_eq!(through.len(), 100);
    assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo(), "the FIFO was replaced by a file");
    assert!(!dir.join("fifo.part").exists());
    // Into /dev/null (a device) too, with --force: it stays a device.
    let (status, json) =
        run(&addr, &["read", "--from", SERVER, "--length", "16", "--force", "--out", "/dev/null"]).await;
    assert_eq!(status, 0, "{json}");
    assert!(std::fs::metadata("/dev/null").unwrap().file_type().is_char_device());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unknown_node_exits_5() {
    let dir = scratch("unknown");
    let (_hub, addr) = hub().await;
    let out = dir.join("never.bin");
    let (status, json) = run(&addr, &["read", "--from", "05.01.01.01.22.EE", "--out", path_arg(&out)]).await;
    assert_eq!(status, 5, "{json}");
    assert_eq!(json["result"], "not_found");
    assert!(!out.exists() && !dir.join("never.bin.part").exists());
    let image = dir.join("image.bin");
    std::fs::write(&image, data(10, 0)).unwrap();
    let (status, _) = run(&addr, &["firmware", path_arg(&image), "--to", "05.01.01.01.22.EE"]).await;
    assert_eq!(status, 5);
    let (status, _) = run(&addr, &["write", path_arg(&image), "--to", "05.01.01.01.22.EE"]).await;
    assert_eq!(status, 5);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_stops_serve_with_exit_130_and_its_report() {
    let dir = scratch("sigterm");
    let (_hub, addr) = hub().await;
    let out = dir.join("image.bin");
    let mut server = Server::start(&dir, &addr, SERVER, &["--firmware-out", path_arg(&out)]).await;
    let image = dir.join("upgrade.bin");
    std::fs::write(&image, data(3000, 8)).unwrap();
    assert_eq!(run(&addr, &["firmware", path_arg(&image), "--to", SERVER]).await.0, 0);
    server.wait_for("written to").await;
    // A second image never replaces the first without --force: it takes a fresh name.
    let second = dir.join("second.bin");
    std::fs::write(&second, data(1000, 9)).unwrap();
    assert_eq!(run(&addr, &["firmware", path_arg(&second), "--to", SERVER]).await.0, 0);
    server.wait_for("written to").await;
    assert_eq!(std::fs::read(dir.join("image-1.bin")).unwrap(), data(1000, 9));
    let pid = server.child.id().unwrap().to_string();
    let killed = Command::new("kill").args(["-TERM", &pid]).status();
    assert!(bounded("kill", killed).await.unwrap().success());
    let status = bounded("serve's exit", server.child.wait()).await.unwrap();
    assert_eq!(status.code(), Some(130));
    assert_eq!(std::fs::read(&out).unwrap(), data(3000, 8));
}

// ----- the CDI and `config` -----

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_cdi_is_saved_as_clean_xml_by_cdi_and_by_read() {
    let dir = scratch("cdi-clean");
    let (_hub, addr) = hub().await;
    let _server = Server::start(&dir, &addr, SERVER, &[]).await;
    let by_cdi = dir.join("by-cdi.xml");
    let (status, json) = run(&addr, &["cdi", "--from", SERVER, "--out", path_arg(&by_cdi)]).await;
    assert_eq!(status, 0, "{json}");
    let by_read = dir.join("by-read.xml");
    let (status, _) = run(&addr, &["read", "--from", SERVER, "--space", "0xFF", "--out", path_arg(&by_read)]).await;
    assert_eq!(status, 0);
    for file in [&by_cdi, &by_read] {
        let xml = std::fs::read(file).unwrap();
        assert!(!xml.contains(&0), "no NUL in {}", file.display());
        assert!(xml.ends_with(b"</cdi>\n"));
        openlcb_cdi::Layout::parse(std::str::from_utf8(&xml).unwrap()).unwrap();
    }
    assert_eq!(json["bytes"], std::fs::read(&by_cdi).unwrap().len());
}

/// `config backup`, `set` then `restore` of the old backup: the node holds what it held,
/// and only the changed entries were written.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn config_backup_set_restore_round_trip() {
    let dir = scratch("config-roundtrip");
    let (_hub, addr) = hub().await;
    let config = dir.join("config.bin");
    std::fs::write(&config, vec![0; 256]).unwrap();
    let mut server = Server::start(&dir, &addr, SERVER, &["--config", path_arg(&config), "--name", "Yard"]).await;
    let before = dir.join("before.txt");
    let (status, json) = run(&addr, &["config", "backup", SERVER, "--out", path_arg(&before)]).await;
    assert_eq!(status, 0, "{json}");
    let saved = std::fs::read_to_string(&before).unwrap();
    assert!(saved.starts_with("User identification.User name=Yard\nUser identification.User description=\nConfiguration.Label=\nConfiguration.Mode=0\n"), "{saved}");
    assert_eq!(json["entries"], saved.lines().count());

    let (status, json) = run(&addr, &["config", "set", SERVER, "Configuration.Mode", "Test"]).await;
    assert_eq!(status, 0, "{json}");
    assert_eq!(
        (json["value"].as_i64(), json["label"].as_str(), json["old"].as_i64()),
        (Some(2), Some("Test"), Some(0))
    );
    server.wait_for("update complete").await;
    let event = "Configuration.Port(2).Event Off";
    let (status, _) = run(&addr, &["config", "set", SERVER, event, "05.01.01.01.22.E2.00.2A"]).await;
    assert_eq!(status, 0);
    let (status, _) = run(&addr, &["config", "set", SERVER, "Configuration.Label", "Branch"]).await;
    assert_eq!(status, 0);
    let (_, json) = run(&addr, &["config", "get", SERVER, event]).await;
    assert_eq!(json["value"], "05.01.01.01.22.E2.00.2A");
    let held = std::fs::read(&config).unwrap();
    assert_eq!(&held[..7], b"Branch\0", "strings are NUL-padded to their size");
    assert!(held[7..32].iter().all(|b| *b == 0));

    let (status, json) = run(&addr, &["config", "restore", SERVER, path_arg(&before), "--dry-run"]).await;
    assert_eq!(status, 0, "{json}");
    assert_eq!(json["written"].as_array().unwrap().len(), 3);
    assert_ne!(std::fs::read(&config).unwrap(), vec![0; 256], "a dry run writes nothing");
    let (status, json) = run(&addr, &["config", "restore", SERVER, path_arg(&before)]).await;
    assert_eq!(status, 0, "{json}");
    let written: Vec<&str> = json["written"].as_array().unwrap().iter().filter_map(|k| k.as_str()).collect();
    assert_eq!(written, ["Configuration.Label", "Configuration.Mode", event]);
    assert_eq!(json["unchanged"], saved.lines().count() - 3);
    assert_eq!(std::fs::read(&config).unwrap(), vec![0; 256]);
    let after = dir.join("after.txt");
    let (status, _) = run(&addr, &["config", "backup", SERVER, "--out", path_arg(&after)]).await;
    assert_eq!(status, 0);
    assert_eq!(std::fs::read_to_string(&after).unwrap(), saved);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn config_refuses_what_the_cdi_does_not_allow_and_writes_nothing() {
    let (dir, _hub, addr, config, _server) = serve_zeros("config-refuse").await;
    for (key, value) in [
        ("Configuration.Delay (ms)", "1001"),
        ("Configuration.Mode", "Sleeping"),
        ("Configuration.Mode", "7"),
        ("Configuration.Label", &"x".repeat(32)),
        ("Configuration.Port(0).Event On", "05.01.01"),
        ("Configuration.Scale", "101"),
        ("Configuration.No such thing", "1"),
    ] {
        let (status, json) = run(&addr, &["config", "set", SERVER, key, value]).await;
        assert_eq!((status, json["result"].as_str()), (2, Some("usage")), "{key}={value}: {json}");
    }
    let backup = dir.join("edited.txt");
    std::fs::write(&backup, "Configuration.Mode=1\nConfiguration.Delay (ms)=5000\n").unwrap();
    let (status, json) = run(&addr, &["config", "restore", SERVER, path_arg(&backup)]).await;
    assert_eq!((status, json["result"].as_str()), (2, Some("usage")), "{json}");
    assert!(json["error"].as_str().unwrap().contains("Delay"));
    assert_eq!(std::fs::read(&config).unwrap(), vec![0; 256], "nothing written, not even the valid line");
    let renamed = dir.join("renamed.txt");
    std::fs::write(&renamed, "# made by hand\nConfiguration.Old Mode=1\nConfiguration.Delay (ms)=250\n").unwrap();
    let (status, json) = run(&addr, &["config", "restore", SERVER, path_arg(&renamed)]).await;
    assert_eq!(status, 0, "{json}");
    assert_eq!(json["unknown_keys"], serde_json::json!(["Configuration.Old Mode"]));
    assert_eq!(&std::fs::read(&config).unwrap()[33..35], [0, 250], "big-endian");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restore_refuses_duplicates_reads_past_a_byte_order_mark_and_bounds_its_input() {
    let (dir, _hub, addr, config, _server) = serve_zeros("config-duplicates").await;
    let twice = dir.join("twice.txt");
    std::fs::write(&twice, "Configuration.Mode=1\nConfiguration.Label=x\nConfiguration.Mode=2\n").unwrap();
    let (status, json) = run(&addr, &["config", "restore", SERVER, path_arg(&twice)]).await;
    assert_eq!((status, json["result"].as_str()), (2, Some("usage")), "{json}");
    let error = json["error"].as_str().unwrap();
    assert!(error.contains("Configuration.Mode on line 1 and again on line 3"), "{error}");
    assert_eq!(std::fs::read(&config).unwrap(), vec![0; 256], "nothing written");
    let marked = dir.join("marked.txt");
    std::fs::write(&marked, "\u{feff}Configuration.Mode=1\n").unwrap();
    let (status, json) = run(&addr, &["config", "restore", SERVER, path_arg(&marked)]).await;
    assert_eq!(status, 0, "{json}");
    assert_eq!(json["written"], serde_json::json!(["Configuration.Mode"]));
    let huge = dir.join("huge.txt");
    std::fs::write(&huge, "Unknown.Key=1\n".repeat(1 << 20)).unwrap();
    let (status, json) = run(&addr, &["config", "restore", SERVER, path_arg(&huge)]).await;
    assert_eq!((status, json["result"].as_str()), (2, Some("usage")), "{json}");
    assert!(json["error"].as_str().unwrap().contains("larger than a backup of this node's CDI can be"), "{json}");
}

/// A CDI of our own shaped like a 16-line I/O board, served by `serve --cdi`: `show` gives
/// the tree with values and labels, and `backup` one line per int, string and event.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn config_show_and_backup_of_an_io_board_cdi() {
    let dir = scratch("config-io16");
    let (_hub, addr) = hub().await;
    let cdi = concat!(env!("CARGO_MANIFEST_DIR"), "/../openlcb-cdi/tests/cdi/io16.xml");
    let config = dir.join("config.bin");
    let mut bytes = vec![0; 2 + 16 * 39 + 1];
    bytes[1] = 20;
    bytes[2 + 5 * 39 + 16] = 2; // Line 6 is an output
    std::fs::write(&config, &bytes).unwrap();
    let _server = Server::start(&dir, &addr, SERVER, &["--cdi", cdi, "--config", path_arg(&config)]).await;
    let (status, json) = run(&addr, &["config", "show", SERVER]).await;
    assert_eq!(status, 0, "{json}");
    let settings = &json["segments"][1];
    assert_eq!(settings["key"], "Settings");
    assert_eq!(settings["children"][0]["value"], 20);
    assert_eq!(settings["children"][0]["min"], 1);
    let line6 = &settings["children"][1]["children"][5];
    assert_eq!(line6["name"], "Line 6");
    assert_eq!(line6["children"][1]["label"], "Output");
    assert_eq!(line6["children"][1]["map"][2], serde_json::json!({ "value": "2", "label": "Output" }));
    assert_eq!(line6["children"][4]["children"][1]["name"], "Off");
    let out = dir.join("io16.txt");
    let (status, _) = run(&addr, &["config", "backup", SERVER, "--out", path_arg(&out)]).await;
    assert_eq!(status, 0);
    let text = std::fs::read_to_string(&out).unwrap();
    assert_eq!(text.lines().count(), 100);
    assert!(text.contains("\nSettings.Line(5).Function=2\nSettings.Line(5).Event On=00.00.00.00.00.00.00.00\n"));
}

/// The Node ID of the replacement in [`FreshBoard`].
const REPLACEMENT: &str = "05.01.01.01.22.E3";

/// A factory-fresh board (every configuration byte 0xFF: erased strings, ints past their
/// `max`) as SERVER and a replacement holding zeros as REPLACEMENT, both `serve --cdi` of the
/// same 16-line CDI, on one hub. Dropped, it stops both.
struct FreshBoard {
    dir: std::path::PathBuf,
    _hub: Hub,
    addr: String,
    /// The replacement's configuration file.
    replacement: std::path::PathBuf,
    _servers: [Server; 2],
}

impl FreshBoard {
    async fn start(test: &str) -> FreshBoard {
        let dir = scratch(test);
        let (hub, addr) = hub().await;
        let cdi = concat!(env!("CARGO_MANIFEST_DIR"), "/../openlcb-cdi/tests/cdi/io16.xml");
        let (fresh, replacement) = (dir.join("fresh.bin"), dir.join("replacement.bin"));
        std::fs::write(&fresh, vec![0xFF; 2 + 16 * 39 + 1]).unwrap();
        std::fs::write(&replacement, vec![0; 2 + 16 * 39 + 1]).unwrap();
        let board = Server::start(&dir, &addr, SERVER, &["--cdi", cdi, "--config", path_arg(&fresh)]).await;
        let new = Server::start(&dir, &addr, REPLACEMENT, &["--cdi", cdi, "--config", path_arg(&replacement)]).await;
        FreshBoard { dir, _hub: hub, addr, replacement, _servers: [board, new] }
    }
}

/// A factory-fresh board (every configuration byte 0xFF: erased strings, ints past their
/// `max`) is backed up, restored onto a replacement that holds zeros, and the replacement's
/// backup is the board's, byte for byte.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_factory_fresh_backup_restores_onto_a_replacement() {
    let board = FreshBoard::start("config-fresh").await;
    let (dir, addr, replacement) = (&board.dir, &board.addr, &board.replacement);
    let (board_backup, new_backup) = (dir.join("board.txt"), dir.join("new.txt"));
    let (status, json) = run(addr, &["config", "backup", SERVER, "--out", path_arg(&board_backup)]).await;
    assert_eq!(status, 0, "{json}");
    let text = std::fs::read_to_string(&board_backup).unwrap();
    assert!(text.contains(&format!("\nSettings.Line(0).Label={}\n", "\u{FFFD}".repeat(16))), "{text}");
    assert!(text.contains("\nSettings.Debounce (ms)=65535\n"), "{text}");
    let (status, json) = run(addr, &["config", "restore", REPLACEMENT, path_arg(&board_backup)]).await;
    assert_eq!(status, 0, "{json}");
    assert_eq!(std::fs::read(replacement).unwrap()[..18], [0xFF; 18], "Debounce and Line(0).Label erased");
    let (status, json) = run(addr, &["config", "backup", REPLACEMENT, "--out", path_arg(&new_backup)]).await;
    assert_eq!(status, 0, "{json}");
    assert_eq!(std::fs::read_to_string(&new_backup).unwrap(), text);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_image_that_cannot_be_saved_fails_the_upgrade_and_a_retry_succeeds() {
    let dir = scratch("unsaved");
    let (_hub, addr) = hub().await;
    // An output serve cannot write: refused at start.
    let nowhere = dir.join("missing").join("image.bin");
    let refused = Command::new(BIN)
        .args(["serve", "--connect", &addr, "--firmware-out", path_arg(&nowhere)])
        .stdin(Stdio::null())
        .kill_on_drop(true)
        .output();
    let refused = bounded("serve with an output it cannot write", refused).await.unwrap();
    assert_eq!(refused.status.code(), Some(8));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("cannot write firmware images"));
    // Its folder goes away after the start: the upgrade fails on the wire, by stream and by
    // datagrams, and serve stays frozen, so that a retry once the folder is back works.
    let folder = dir.join("out");
    std::fs::create_dir(&folder).unwrap();
    let out = folder.join("image.bin");
    let mut server = Server::start(&dir, &addr, SERVER, &["--firmware-out", path_arg(&out)]).await;
    std::fs::remove_dir(&folder).unwrap();
    let image = dir.join("upgrade.bin");
    std::fs::write(&image, data(10_000, 4)).unwrap();
    for extra in [None, Some("--no-stream")] {
        let mut args = vec!["firmware", path_arg(&image), "--to", SERVER];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_ne!(status, 0, "{extra:?}: {json}");
        server.wait_for("refused").await;
    }
    std::fs::create_dir(&folder).unwrap();
    let (status, json) = run(&addr, &["firmware", path_arg(&image), "--to", SERVER]).await;
    assert_eq!(status, 0, "{json}");
    server.wait_for("written to").await;
    assert_eq!(std::fs::read(&out).unwrap(), data(10_000, 4));
}

/// The file behind `--config` takes each write command whole, once: bytes across pages (a
/// Write Stream's) by replacing the file (a reader that opened it before still reads the
/// whole earlier version), bytes within a page (a Write datagram's) in place; no `.part` is
/// left.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_config_file_takes_each_write_command_whole() {
    use std::io::Read as _;
    let dir = scratch("config-whole");
    let (_hub, addr) = hub().await;
    let config = dir.join("config.bin");
    std::fs::write(&config, data(12_288, 4)).unwrap();
    let _server = Server::start(&dir, &addr, SERVER, &["--config", path_arg(&config)]).await;

    let mut opened_before = std::fs::File::open(&config).unwrap();
    let mut expected = data(12_288, 4);
    for (key, len, extra) in [(5, 8192, None), (6, 100, Some("--no-stream"))] {
        let restore = dir.join(format!("restore-{key}.bin"));
        std::fs::write(&restore, data(len, key)).unwrap();
        let mut args = vec!["write", path_arg(&restore), "--to", SERVER];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_eq!(status, 0, "{json}");
        assert_eq!(json["path"], if extra.is_none() { "stream" } else { "datagrams" }, "{json}");
        expected[..len].copy_from_slice(&data(len, key));
        assert_eq!(std::fs::read(&config).unwrap(), expected);
        assert!(!dir.join("config.bin.part").exists());
        if key == 5 {
            let mut seen = Vec::new();
            opened_before.read_to_end(&mut seen).unwrap();
            assert_eq!(seen, data(12_288, 4), "the stream's bytes were written in place");
        }
    }
}

/// A write longer than the space is refused before a byte moves, by datagrams as by stream.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_write_larger_than_the_space_is_refused_before_a_byte_is_written() {
    let (dir, _hub, addr, config, _server) = serve_zeros("config-too-long").await;
    let image = dir.join("image.bin");
    std::fs::write(&image, data(300, 6)).unwrap();
    for extra in [None, Some("--no-stream")] {
        let mut args = vec!["write", path_arg(&image), "--to", SERVER];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_ne!(status, 0, "{extra:?}: {json}");
        assert_eq!((json["result"].as_str(), json["bytes"].as_u64()), (Some("rejected"), Some(0)), "{extra:?}: {json}");
        assert!(json["error"].as_str().unwrap().contains("out of bounds"), "{extra:?}: {json}");
        assert_eq!(std::fs::read(&config).unwrap(), vec![0; 256], "{extra:?}: nothing written");
    }
}

/// `write` ends with Update Complete, unless told not to; `reboot` and `factory-reset` reach
/// the node, and `factory-reset` sends nothing without `--yes`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn write_ends_with_update_complete_and_reboot_and_factory_reset_reach_the_node() {
    let (dir, _hub, addr, _config, mut server) = serve_zeros("node-commands").await;
    let image = dir.join("image.bin");
    std::fs::write(&image, data(100, 7)).unwrap();
    let (status, json) = run(&addr, &["write", path_arg(&image), "--to", SERVER]).await;
    assert_eq!(status, 0, "{json}");
    server.wait_for("update complete, said").await;

    let (status, json) = run(&addr, &["factory-reset", SERVER]).await;
    assert_eq!((status, json["result"].as_str()), (2, Some("usage")), "{json}");
    assert!(json["error"].as_str().unwrap().contains("--yes"), "{json}");
    // Nothing was sent: the next line serve prints is the reboot's, not a factory reset.
    let (status, json) = run(&addr, &["reboot", SERVER]).await;
    assert_eq!((status, json["command"].as_str()), (0, Some("reboot")), "{json}");
    let line = server.wait_for(" asked for by ").await;
    assert!(line.contains("reset asked for by") && !line.contains("factory"), "{line}");
    let (status, json) = run(&addr, &["factory-reset", SERVER, "--yes"]).await;
    assert_eq!(status, 0, "{json}");
    server.wait_for("factory reset asked for by").await;
    let (status, json) = run(&addr, &["reboot", "05.01.01.01.22.7E"]).await;
    assert_eq!((status, json["result"].as_str()), (5, Some("not_found")), "{json}");
}

/// What a test relay does with one line its client sends.
enum Route {
    /// To the hub.
    Pass,
    /// Kept from the hub; these frames go back to the client instead.
    Answer(Vec<String>),
    /// To the hub, and from then on nothing more passes either way (the connection stays
    /// open: the client waits for answers that never come).
    PassThenStall,
}

/// A relay between each client and the hub on 127.0.0.1: `route` decides every line a
/// client sends; every line from the hub goes to the client until a stall. Its address.
async fn relay(hub: &str, route: impl Fn(&str) -> Route + Send + Sync + 'static) -> String {
    use std::sync::atomic::{AtomicBool, Ordering::SeqCst};
    use tokio::io::AsyncWriteExt as _;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let (hub, route) = (hub.to_string(), std::sync::Arc::new(route));
    tokio::spawn(async move {
        while let Ok((client, _)) = listener.accept().await {
            let upstream = tokio::net::TcpStream::connect(&hub).await.unwrap();
            let (client_read, client_write) = client.into_split();
            let (hub_read, mut hub_write) = upstream.into_split();
            let client_write = std::sync::Arc::new(tokio::sync::Mutex::new(client_write));
            let stalled = std::sync::Arc::new(AtomicBool::new(false));
            let (answers, stall, route) = (client_write.clone(), stalled.clone(), route.clone());
            tokio::spawn(async move {
                let mut lines = BufReader::new(client_read).lines();
                while let Ok(Some(line)) = lines.next_line().await {
                    if stall.load(SeqCst) {
                        continue;
                    }
                    let frames = match route(&line) {
                        Route::Answer(frames) => frames,
                        pass => {
                            stall.store(matches!(pass, Route::PassThenStall), SeqCst);
                            vec![]
                        }
                    };
                    if frames.is_empty() && hub_write.write_all(format!("{line}\n").as_bytes()).await.is_err() {
                        break;
                    }
                    let mut to_client = answers.lock().await;
                    for frame in frames {
                        let _ = to_client.write_all(format!("{frame}\n").as_bytes()).await;
                    }
                }
            });
            tokio::spawn(async move {
                let mut lines = BufReader::new(hub_read).lines();
                while let Ok(Some(line)) = lines.next_line().await {
                    if !stalled.load(SeqCst)
                        && client_write.lock().await.write_all(format!("{line}\n").as_bytes()).await.is_err()
                    {
                        break;
                    }
                }
            });
        }
    });
    addr
}

/// A relay that keeps from the node every one-frame datagram of a client whose payload is
/// `command` (hex, e.g. `20A8`: Update Complete) and answers it in the node's name with the
/// frames `answer` gives for (the node's alias, the client's alias), as a node that has not
/// that command would; every other frame passes.
async fn relay_answering(hub: &str, command: &'static str, answer: fn(&str, &str) -> Vec<String>) -> String {
    relay(hub, move |line| {
        // A one-frame datagram :X1Adddsss N<payload>; (ddd the node, sss the client).
        if line.starts_with(":X1A") && line.ends_with(&format!("N{command};")) {
            Route::Answer(answer(&line[4..7], &line[7..10]))
        } else {
            Route::Pass
        }
    })
    .await
}

/// Datagram Rejected 0x1041 (not implemented: unknown command) from `node` to `client`.
fn rejected_1041(node: &str, client: &str) -> Vec<String> {
    vec![format!(":X19A48{node}N0{client}1041;")]
}

/// A node that refuses Update Complete after a verified `config set` or `write`: the value
/// is written, so the command succeeds with a warning.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_update_complete_after_a_verified_write_is_a_warning() {
    let (dir, _hub, addr, config, _server) = serve_zeros("update-refused").await;
    let relay = relay_answering(&addr, "20A8", rejected_1041).await;
    let (status, json) = run(&relay, &["config", "set", SERVER, "Configuration.Mode", "1"]).await;
    assert_eq!((status, json["result"].as_str()), (0, Some("ok")), "{json}");
    let warning = json["warning"].as_str().unwrap_or_default();
    assert!(warning.contains("Update Complete failed") && warning.contains("0x1041"), "{json}");
    assert_eq!(std::fs::read(&config).unwrap()[32], 1, "Mode is written");
    let image = dir.join("image.bin");
    std::fs::write(&image, data(100, 8)).unwrap();
    let (status, json) = run(&relay, &["write", path_arg(&image), "--to", SERVER]).await;
    assert_eq!(status, 0, "{json}");
    assert!(json["warning"].as_str().unwrap_or_default().contains("Update Complete failed"), "{json}");
    assert_eq!(std::fs::read(&config).unwrap()[..100], data(100, 8));
    let (status, json) = run(&relay, &["write", path_arg(&image), "--to", SERVER, "--no-update-complete"]).await;
    assert_eq!((status, json.get("warning")), (0, None), "{json}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stream_sent_to_serve_is_refused_not_swallowed() {
    // serve takes streams only for its Memory Configuration (0x1010); with --no-streams it has
    // none, and its PIP says so: the refusal is worded from it.
    let without_streams = format!("this node ({SERVER}) has no streams");
    for (test, extra, said) in [
        ("send-to-serve", &[][..], "streams not supported"),
        ("send-no-streams", &["--no-streams"][..], without_streams.as_str()),
    ] {
        let dir = scratch(test);
        let (_hub, addr) = hub().await;
        let _server = Server::start(&dir, &addr, SERVER, extra).await;
        let input = dir.join("input.bin");
        std::fs::write(&input, data(300, 2)).unwrap();
        let output = Command::new(BIN)
            .args(["send", path_arg(&input), "--to", SERVER, "--connect", &addr])
            .stdin(Stdio::null())
            .kill_on_drop(true)
            .output();
        let output = bounded(test, output).await.unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(4), "{stderr}");
        assert!(stderr.contains(said), "{stderr}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_read_of_the_firmware_space_is_refused_and_says_so() {
    let dir = scratch("read-firmware");
    let (_hub, addr) = hub().await;
    let _server = Server::start(&dir, &addr, SERVER, &[]).await;
    for extra in [None, Some("--no-stream")] {
        let out = dir.join("firmware.bin");
        let mut args = vec!["read", "--from", SERVER, "--space", "0xEF", "--out", path_arg(&out)];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_eq!(status, 4, "{extra:?}: {json}");
        assert_eq!(json["result"], "rejected");
        let error = json["error"].as_str().unwrap();
        assert!(error.contains("0x1040") && error.contains("cannot be read back"), "{error}");
        assert!(!out.exists() && !dir.join("firmware.bin.part").exists());
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_whole_read_of_a_space_larger_than_a_read_takes_fails_at_once_pointing_to_length() {
    let dir = scratch("read-too-large");
    let (_hub, addr) = hub().await;
    let config = dir.join("big.cfg");
    let limit = 16 * 1024 * 1024;
    std::fs::File::create(&config).unwrap().set_len(limit + 1).unwrap();
    let _server = Server::start(&dir, &addr, SERVER, &["--config", path_arg(&config)]).await;
    for extra in [None, Some("--no-stream")] {
        let out = dir.join("backup.bin");
        let mut args = vec!["read", "--from", SERVER, "--out", path_arg(&out)];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_eq!(status, 2, "{extra:?}: {json}");
        assert_eq!((json["result"].as_str(), json["bytes"].as_u64()), (Some("usage"), Some(0)), "{json}");
        let error = json["error"].as_str().unwrap();
        let (size, limit) = ((limit + 1).to_string(), limit.to_string());
        assert!(error.contains(&size) && error.contains(&limit) && error.contains("--length"), "{error}");
    }
    // A part of it is read.
    let out = dir.join("part.bin");
    let args = ["read", "--from", SERVER, "--address", "0x1000000", "--length", "1", "--out", path_arg(&out)];
    assert_eq!(run(&addr, &args).await.0, 0);
    assert_eq!(std::fs::read(&out).unwrap(), [0]);
}

/// Space 0xFD of an in-process node: `len` bytes of `data(len, 9)`, each read taking `delay`
/// (it blocks the node's own thread: a node that trickles), and, after the first time its
/// size is asked, `grown` bytes long (a node whose stream goes on past the size it reported);
/// `reads` counts the reads served.
struct OddSpace {
    bytes: Vec<u8>,
    delay: std::time::Duration,
    grown: u32,
    asked: std::sync::atomic::AtomicBool,
    reads: std::sync::Arc<std::sync::atomic::AtomicUsize>,
}

impl MemorySpace for OddSpace {
    fn len(&self) -> u32 {
        let again = self.asked.swap(true, std::sync::atomic::Ordering::Relaxed);
        if again { self.grown } else { self.bytes.len() as u32 }
    }
    fn read_only(&self) -> bool {
        true
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        std::thread::sleep(self.delay);
        self.reads.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let at = (address as usize).min(self.bytes.len());
        let n = buf.len().min(self.grown as usize - address as usize);
        let held = self.bytes.get(at..).unwrap_or_default();
        for (i, b) in buf.iter_mut().take(n).enumerate() {
            *b = held.get(i).copied().unwrap_or(0);
        }
        Ok(n)
    }
    fn write(&mut self, _address: u32, _data: &[u8]) -> Result<(), SpaceError> {
        Err(SpaceError::ReadOnly)
    }
}

/// A node on `hub` with `server`'s spaces (none: a node without Memory Configuration), on
/// a thread and runtime of its own; it runs until the test's process ends.
async fn node_in_process(hub: &str, server: Option<MemoryServer>) {
    let (ready, is_ready) = tokio::sync::oneshot::channel();
    let hub = hub.to_string();
    std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        runtime.block_on(async move {
            let options = NodeOptions::new(SERVER.parse().unwrap());
            let node = Node::connect(&hub, Framing::GridConnect, options).await.unwrap();
            let _events = match server {
                Some(server) => Some(node.set_memory_server(server).await.unwrap()),
                None => None,
            };
            let _ = ready.send(());
            std::future::pending::<()>().await;
        });
    });
    bounded("the in-process node", is_ready).await.unwrap();
}

/// Serves `space` as 0xFD from a node on `hub` (see [`node_in_process`]).
async fn serve_in_process(hub: &str, space: OddSpace) {
    node_in_process(hub, Some(MemoryServer::new().with_space(0xFD, space))).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_read_from_a_node_that_trickles_ends_below_the_minimum_rate() {
    let (_hub, addr) = hub().await;
    let len = 1024 * 1024;
    let delay = std::time::Duration::from_millis(50);
    let space =
        OddSpace { bytes: data(len, 9), delay, grown: len as u32, asked: false.into(), reads: Default::default() };
    serve_in_process(&addr, space).await;
    let dir = scratch("trickle");
    for extra in [None, Some("--no-stream")] {
        let out = dir.join("slow.bin");
        let mut args = vec!["read", "--from", SERVER, "--out", path_arg(&out), "--min-rate", "100000", "--grace", "1"];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_eq!((status, json["result"].as_str()), (5, Some("timed_out")), "{extra:?}: {json}");
        let error = json["error"].as_str().unwrap();
        assert!(error.contains("--min-rate 100000") && error.contains("--grace of 1 s"), "{error}");
        assert!(!out.exists() && !dir.join("slow.bin.part").exists());
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stream_longer_than_the_space_reported_is_a_bad_answer() {
    let (_hub, addr) = hub().await;
    let delay = std::time::Duration::ZERO;
    let space = OddSpace { bytes: data(600, 9), delay, grown: 1024, asked: false.into(), reads: Default::default() };
    serve_in_process(&addr, space).await;
    let dir = scratch("overrun");
    let out = dir.join("backup.bin");
    let (status, json) = run(&addr, &["read", "--from", SERVER, "--out", path_arg(&out)]).await;
    assert_eq!((status, json["result"].as_str()), (11, Some("bad_answer")), "{json}");
    let error = json["error"].as_str().unwrap();
    assert!(error.contains("sent more than 600 bytes"), "{error}");
    assert!(!out.exists() && !dir.join("backup.bin.part").exists());
}

// ----- a tool that vanished: its upgrade and its lock end, a rerun gets through -----

/// A tool that logs in by hand as 05.01.01.01.22.F0 (alias 0x5A5), sends `command` to
/// SERVER in one datagram frame, waits for its Datagram Received OK and vanishes: its socket
/// closes with no AMR, as `kill -9` of a tool on a GridConnect hub leaves it.
async fn vanish_after(hub: &str, command: &[u8]) {
    use tokio::io::AsyncWriteExt as _;
    let (read, mut write) = tokio::net::TcpStream::connect(hub).await.unwrap().into_split();
    let login = ":X170505A5N;:X161015A5N;:X150125A5N;:X142F05A5N;:X107005A5N;:X107015A5N0501010122F0;";
    write.write_all(format!("{login}:X107025A5N;\n").as_bytes()).await.unwrap();
    let mut lines = BufReader::new(read).lines();
    let amd = format!("N{};", SERVER.replace('.', ""));
    let server_alias = bounded("SERVER's AMD", async {
        loop {
            let line = lines.next_line().await.unwrap().unwrap();
            if line.starts_with(":X10701") && line.ends_with(&amd) {
                break line[7..10].to_string();
            }
        }
    })
    .await;
    let hex: String = command.iter().map(|b| format!("{b:02X}")).collect();
    write.write_all(format!(":X1A{server_alias}5A5N{hex};\n").as_bytes()).await.unwrap();
    let ok = format!(":X19A28{server_alias}N05A5");
    bounded("the Datagram Received OK", async { while !lines.next_line().await.unwrap().unwrap().starts_with(&ok) {} })
        .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_frozen_by_a_vanished_loader_is_taken_over_by_a_rerun() {
    let dir = scratch("vanished-loader");
    let (_hub, addr) = hub().await;
    let out = dir.join("image.bin");
    let mut server = Server::start(&dir, &addr, SERVER, &["--firmware-out", path_arg(&out)]).await;
    vanish_after(&addr, &[0x20, 0xA1, 0xEF]).await;
    let image = dir.join("upgrade.bin");
    std::fs::write(&image, data(3000, 4)).unwrap();
    let (status, json) = run(&addr, &["firmware", path_arg(&image), "--to", SERVER]).await;
    assert_eq!(status, 0, "{json}");
    server.wait_for("written to").await;
    assert_eq!(std::fs::read(&out).unwrap(), data(3000, 4));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lock_left_by_a_vanished_tool_does_not_hold_up_the_next_write() {
    let (dir, _hub, addr, config, _server) = serve_zeros("vanished-lock").await;
    // Lock/Reserve naming the vanishing tool's Node ID.
    vanish_after(&addr, &[0x20, 0x88, 0x05, 0x01, 0x01, 0x01, 0x22, 0xF0]).await;
    let image = dir.join("values.bin");
    std::fs::write(&image, data(200, 6)).unwrap();
    let (status, json) = run(&addr, &["write", path_arg(&image), "--to", SERVER, "--no-stream"]).await;
    assert_eq!(status, 0, "{json}");
    assert_eq!(std::fs::read(&config).unwrap()[..200], data(200, 6));
}

/// A relay that passes everything until its client has sent `writes` Write datagrams, then
/// stalls (see [`Route::PassThenStall`]); `stalled` is told when it stops.
async fn relay_stalling_after(hub: &str, writes: usize, stalled: mpsc::UnboundedSender<()>) -> String {
    let seen = std::sync::atomic::AtomicUsize::new(0);
    relay(hub, move |line| {
        // The first (or only) frame of a datagram whose command is a Write (20 00..03).
        let data = line.split_once('N').map_or("", |(_, d)| d);
        let write = (line.starts_with(":X1A") || line.starts_with(":X1B")) && data.len() >= 4 && &data[..3] == "200";
        if write && seen.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1 == writes {
            let _ = stalled.send(());
            return Route::PassThenStall;
        }
        Route::Pass
    })
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_interrupted_restore_says_how_many_settings_it_wrote_and_a_rerun_finishes() {
    let board = FreshBoard::start("restore-interrupted").await;
    let (dir, addr) = (&board.dir, &board.addr);
    let backup = dir.join("board.txt");
    let (status, json) = run(addr, &["config", "backup", SERVER, "--out", path_arg(&backup)]).await;
    assert_eq!(status, 0, "{json}");

    // The restore by datagrams stalls after its third Write; Ctrl-C then.
    let (stalled, mut stall) = mpsc::unbounded_channel();
    let relay = relay_stalling_after(addr, 3, stalled).await;
    let restore = Command::new(BIN)
        .args(["config", "restore", REPLACEMENT, path_arg(&backup), "--no-stream", "--connect", &relay, "--json"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    bounded("the third write", stall.recv()).await;
    common::interrupt(&restore).await;
    let output = bounded("the interrupted restore", restore.wait_with_output()).await.unwrap();
    let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!((output.status.code(), json["result"].as_str()), (Some(130), Some("interrupted")), "{json}");
    let error = json["error"].as_str().unwrap_or_default();
    // Two Writes were answered before the stall (64 bytes each: the settings wholly inside).
    let settings: usize = std::fs::read_to_string(&backup).unwrap().lines().filter(|l| l.contains('=')).count();
    assert!(error.contains(" settings were written before it stopped"), "{json}");
    let written: usize = error.split(" of ").next().and_then(|s| s.rsplit(' ').next()).unwrap().parse().unwrap();
    assert!(written > 0 && written < settings, "{json}");

    // At once, by another transient Node ID: the interrupted tool's lock does not stop it.
    let (status, json) = run(addr, &["config", "restore", REPLACEMENT, path_arg(&backup)]).await;
    assert_eq!(status, 0, "{json}");
    let again = dir.join("again.txt");
    let (status, _) = run(addr, &["config", "backup", REPLACEMENT, "--out", path_arg(&again)]).await;
    assert_eq!(status, 0);
    assert_eq!(std::fs::read_to_string(&again).unwrap(), std::fs::read_to_string(&backup).unwrap());
}

// ----- CDIs that cannot be taken; refusals in words -----

/// The most bytes a CDI may have (`lcc-stream cdi --help`).
const MAX_CDI_BYTES: usize = 1024 * 1024;

/// An empty CDI (`serve --cdi` of an empty file, or of white space) is an error in words,
/// exit 11, for `cdi` (no file written) and for `config`, by stream and by datagrams.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_empty_cdi_is_an_error_and_no_file_is_written() {
    let dir = scratch("cdi-empty");
    let (_hub, addr) = hub().await;
    let (empty, blank) = (dir.join("empty.xml"), dir.join("blank.xml"));
    std::fs::write(&empty, b"").unwrap();
    std::fs::write(&blank, b" \n\t\r\n").unwrap();
    const BLANK: &str = "05.01.01.01.22.E3";
    let _empty = Server::start(&dir, &addr, SERVER, &["--cdi", path_arg(&empty)]).await;
    let _blank = Server::start(&dir, &addr, BLANK, &["--cdi", path_arg(&blank)]).await;
    for (node, extra) in [(SERVER, None), (BLANK, Some("--no-stream"))] {
        let out = dir.join("cdi.xml");
        let mut args = vec!["cdi", "--from", node, "--out", path_arg(&out)];
        args.extend(extra);
        let (status, json) = run(&addr, &args).await;
        assert_eq!((status, json["result"].as_str()), (11, Some("bad_answer")), "{node}: {json}");
        let error = json["error"].as_str().unwrap();
        assert!(error.contains(&format!("the CDI of node {node} is empty")), "{error}");
        assert!(!out.exists() && !dir.join("cdi.xml.part").exists(), "{node}: a file was written");
        let (status, json) = run(&addr, &["config", "show", node]).await;
        assert_eq!(status, 11, "{node}: {json}");
        assert!(json["error"].as_str().unwrap().contains("is empty"), "{json}");
    }
}

/// A CDI space that reports more than a CDI may have (an unterminated 2 MiB of text) is
/// refused before a byte is read, naming the bound, by `cdi` (by stream and by datagrams),
/// `config show`, `config backup` and `config restore`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cdi_larger_than_the_bound_is_refused_before_it_is_read() {
    let dir = scratch("cdi-huge");
    let (_hub, addr) = hub().await;
    let huge = dir.join("huge.xml");
    std::fs::write(&huge, "<".repeat(2 * MAX_CDI_BYTES)).unwrap();
    let _server = Server::start(&dir, &addr, SERVER, &["--cdi", path_arg(&huge)]).await;
    let (out, backup) = (dir.join("cdi.xml"), dir.join("backup.txt"));
    std::fs::write(&backup, "Configuration.Mode=1\n").unwrap();
    let cdi = ["cdi", "--from", SERVER, "--out", path_arg(&out)];
    let cdi_by_datagrams = ["cdi", "--from", SERVER, "--out", path_arg(&out), "--no-stream"];
    let show = ["config", "show", SERVER];
    let save = ["config", "backup", SERVER];
    let restore = ["config", "restore", SERVER, path_arg(&backup)];
    for args in [&cdi[..], &cdi_by_datagrams, &show, &save, &restore] {
        let (status, json) = run(&addr, args).await;
        assert_eq!((status, json["result"].as_str()), (11, Some("bad_answer")), "{args:?}: {json}");
        let error = json["error"].as_str().unwrap();
        let size = (2 * MAX_CDI_BYTES + 1).to_string();
        assert!(error.contains("too large") && error.contains(&size), "{error}");
        assert!(error.contains(&MAX_CDI_BYTES.to_string()) && error.contains("1 MiB"), "{error}");
        assert!(!out.exists() && !dir.join("cdi.xml.part").exists());
    }
}

/// Get Address Space Information not present for space 0xFF, as a node without it answers.
fn space_ff_not_present(node: &str, client: &str) -> Vec<String> {
    vec![format!(":X19A28{node}N0{client}80;"), format!(":X1A{client}{node}N2086FF;")]
}

/// A node that refuses Get Address Space Information for its CDI (Datagram Rejected, or
/// a reply that says "not present") is still read to the end, by datagrams and by stream,
/// and its CDI is the one it serves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cdi_is_read_from_a_node_that_refuses_get_address_space_information() {
    let dir = scratch("cdi-no-info");
    let (_hub, addr) = hub().await;
    let _server = Server::start(&dir, &addr, SERVER, &[]).await;
    let direct = dir.join("direct.xml");
    assert_eq!(run(&addr, &["cdi", "--from", SERVER, "--out", path_arg(&direct)]).await.0, 0);
    let served = std::fs::read(&direct).unwrap();
    let refusing = relay_answering(&addr, "2084FF", rejected_1041).await;
    let not_present = relay_answering(&addr, "2084FF", space_ff_not_present).await;
    for (relay, extra) in [(&refusing, None), (&refusing, Some("--no-stream")), (&not_present, Some("--no-stream"))] {
        let out = dir.join("cdi.xml");
        let _ = std::fs::remove_file(&out);
        let mut args = vec!["cdi", "--from", SERVER, "--out", path_arg(&out)];
        args.extend(extra);
        let (status, json) = run(relay, &args).await;
        assert_eq!(status, 0, "{extra:?}: {json}");
        assert_eq!(std::fs::read(&out).unwrap(), served, "{extra:?}");
        let (status, json) = run(relay, &["config", "show", SERVER, "--no-stream"]).await;
        assert_eq!(status, 0, "{json}");
    }
}

/// A node that gives no size for its CDI and whose CDI runs on past the bound without a
/// NUL fails once the bound is passed, naming it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cdi_of_unknown_size_with_no_end_within_the_bound_fails_naming_it() {
    let dir = scratch("cdi-no-end");
    let (_hub, addr) = hub().await;
    let huge = dir.join("huge.xml");
    std::fs::write(&huge, "<".repeat(2 * MAX_CDI_BYTES)).unwrap();
    let _server = Server::start(&dir, &addr, SERVER, &["--cdi", path_arg(&huge)]).await;
    let relay = relay_answering(&addr, "2084FF", rejected_1041).await;
    let out = dir.join("cdi.xml");
    let (status, json) = run(&relay, &["cdi", "--from", SERVER, "--out", path_arg(&out)]).await;
    assert_eq!((status, json["result"].as_str()), (11, Some("bad_answer")), "{json}");
    let error = json["error"].as_str().unwrap();
    assert!(error.contains("has no end") && error.contains(&MAX_CDI_BYTES.to_string()), "{error}");
    assert!(!out.exists() && !dir.join("cdi.xml.part").exists());
}

/// A node whose PIP lists no Memory Configuration: "this node has no configuration".
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_without_memory_configuration_has_no_configuration_in_words() {
    let dir = scratch("no-configuration");
    let (_hub, addr) = hub().await;
    node_in_process(&addr, None).await;
    let out = dir.join("config.bin");
    for args in [&["read", "--from", SERVER, "--out", path_arg(&out)][..], &["config", "show", SERVER]] {
        let (status, json) = run(&addr, args).await;
        assert_eq!((status, json["result"].as_str()), (4, Some("rejected")), "{args:?}: {json}");
        let error = json["error"].as_str().unwrap();
        assert!(error.contains(&format!("this node ({SERVER}) has no configuration")), "{error}");
    }
}

/// A node without Firmware Upgrade in its PIP that refuses Freeze with 0x1041: "this node
/// has no firmware upgrade", exit 4.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_without_firmware_upgrade_has_no_firmware_upgrade_in_words() {
    let dir = scratch("no-firmware-upgrade");
    let (_hub, addr) = hub().await;
    node_in_process(&addr, Some(MemoryServer::new().with_space(0xFD, RamSpace::new(64)))).await;
    let relay = relay_answering(&addr, "20A1EF", rejected_1041).await;
    let image = dir.join("image.bin");
    std::fs::write(&image, data(100, 1)).unwrap();
    let (status, json) = run(&relay, &["firmware", path_arg(&image), "--to", SERVER]).await;
    assert_eq!((status, json["result"].as_str()), (4, Some("rejected")), "{json}");
    let error = json["error"].as_str().unwrap();
    assert!(error.contains("has no firmware upgrade") && error.contains("0x1041"), "{error}");
}

/// A stream sent to a node without streams (`serve --no-streams`, OIR 0x1043): "this node
/// has no streams", exit 4.
/// Sends `child` Ctrl-C once `served` (a count the test's space keeps of its reads or writes)
/// has grown by `count`, and returns how the command ended.
async fn interrupt_after(child: Child, served: &std::sync::atomic::AtomicUsize, count: usize) -> std::process::Output {
    use std::sync::atomic::Ordering;
    let before = served.load(Ordering::Relaxed);
    bounded("the node serving the command", async {
        while served.load(Ordering::Relaxed) < before + count {
            tokio::time::sleep(std::time::Duration::from_millis(10)).await;
        }
    })
    .await;
    common::interrupt(&child).await;
    bounded("the exit after Ctrl-C", child.wait_with_output()).await.unwrap()
}

/// Ctrl-C (SIGINT) in the middle of `read --out FILE` from a node that trickles, by
/// datagrams and by stream: exit 130, FILE.part kept with the first bytes of the space, and
/// the message says how many; FILE is not made.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ctrl_c_on_read_keeps_the_part_and_says_how_many_bytes_it_holds() {
    let (_hub, addr) = hub().await;
    let len = 1024 * 1024;
    let reads = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let delay = std::time::Duration::from_millis(20);
    let space = OddSpace { bytes: data(len, 9), delay, grown: len as u32, asked: false.into(), reads: reads.clone() };
    serve_in_process(&addr, space).await;
    let dir = scratch("read-interrupted");
    for extra in [Some("--no-stream"), None] {
        let out = dir.join("slow.bin");
        let part = dir.join("slow.bin.part");
        let _ = std::fs::remove_file(&part);
        let mut args = vec!["read", "--from", SERVER, "--out", path_arg(&out), "--connect", &addr];
        args.extend(extra);
        // Ctrl-C once some bytes have been served (the first read answers the size, the rest data).
        let output = interrupt_after(common::spawn(&args), &reads, 40).await;
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(130), "{extra:?}: {stderr}");
        let kept = std::fs::read(&part).unwrap();
        assert!(!kept.is_empty() && kept.len() < len, "{extra:?}: {} bytes kept", kept.len());
        assert_eq!(kept, data(len, 9)[..kept.len()], "{extra:?}: the first bytes of the space");
        let said = format!("interrupted: {} holds {} bytes", part.display(), kept.len());
        assert!(stderr.contains(&said), "{extra:?}: {stderr}");
        assert!(!out.exists());
    }
}

/// Bytes a space holds, shared with the test.
type SharedBytes = std::sync::Arc<std::sync::Mutex<Vec<u8>>>;

/// A writable space that takes `delay` for every write and keeps what it was given where the
/// test can see it.
struct SlowSpace {
    bytes: SharedBytes,
    delay: std::time::Duration,
    writes: std::sync::Arc<std::sync::atomic::AtomicUsize>,
}

impl MemorySpace for SlowSpace {
    fn len(&self) -> u32 {
        self.bytes.lock().unwrap().len() as u32
    }
    fn read_only(&self) -> bool {
        false
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        let bytes = self.bytes.lock().unwrap();
        let held = bytes.get(address as usize..).unwrap_or_default();
        let n = buf.len().min(held.len());
        buf[..n].copy_from_slice(&held[..n]);
        Ok(n)
    }
    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        std::thread::sleep(self.delay);
        self.writes.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let mut bytes = self.bytes.lock().unwrap();
        let at = address as usize;
        bytes.get_mut(at..at + data.len()).ok_or(SpaceError::OutOfBounds)?.copy_from_slice(data);
        Ok(())
    }
}

/// Ctrl-C (SIGINT) in the middle of `write` (by datagrams and by stream) and of `firmware`,
/// which run on a runtime of one thread: each exits 130 at once, and what the node stored
/// is the file's first bytes, nothing else.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ctrl_c_on_write_and_firmware_ends_them_with_the_node_holding_the_files_first_bytes() {
    use std::sync::atomic::Ordering;
    let (_hub, addr) = hub().await;
    let len = 256 * 1024;
    let delay = std::time::Duration::from_millis(5);
    let writes = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let config = SharedBytes::new(std::sync::Mutex::new(vec![0u8; len]));
    let firmware = SharedBytes::new(std::sync::Mutex::new(vec![0u8; len]));
    let space = |bytes: &SharedBytes| SlowSpace { bytes: bytes.clone(), delay, writes: writes.clone() };
    let server = MemoryServer::new().with_space(0xFD, space(&config)).with_space(0xEF, space(&firmware));
    node_in_process(&addr, Some(server)).await;
    let dir = scratch("write-interrupted");
    let file = dir.join("image.bin");
    std::fs::write(&file, data(len, 4)).unwrap();
    let runs: [(&[&str], &SharedBytes); 3] = [
        (&["write", "--to", SERVER, "--space", "0xFD", "--no-stream"], &config),
        (&["write", "--to", SERVER, "--space", "0xFD"], &config),
        (&["firmware", "--to", SERVER], &firmware),
    ];
    for (command, stored) in runs {
        stored.lock().unwrap().fill(0);
        let mut args = command.to_vec();
        args.extend([path_arg(&file), "--connect", &addr]);
        let output = interrupt_after(common::spawn(&args), &writes, 20).await;
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(130), "{command:?}: {stderr}");
        assert!(stderr.contains("interrupted"), "{command:?}: {stderr}");
        // The node writes what had arrived before the transfer ended (each write takes
        // `delay` on its thread); then it holds the file's first bytes, and the next command
        // finds it answering again.
        bounded("the node's last writes", async {
            loop {
                let seen = writes.load(Ordering::Relaxed);
                tokio::time::sleep(std::time::Duration::from_millis(200)).await;
                if writes.load(Ordering::Relaxed) == seen {
                    break;
                }
            }
        })
        .await;
        let stored = stored.lock().unwrap().clone();
        let written = stored.iter().rposition(|&b| b != 0).map_or(0, |last| last + 1);
        assert!(written > 0 && written < len, "{command:?}: {written} bytes stored");
        assert_eq!(stored[..written], data(len, 4)[..written], "{command:?}: the file's first bytes");
    }
}
