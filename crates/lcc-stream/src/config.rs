//! `lcc-stream config`: a node's settings by the names its CDI gives them: `show`, `get`,
//! `set`, and JMRI-compatible `backup` and `restore`.
//!
//! Every command reads the CDI first (space 0xFF) and lays it out with `openlcb-cdi`. `show`
//! and `backup` then read each segment's span in one operation (by stream where the node
//! can). `set` and `restore` check every value against its entry (type, size, range, map)
//! before anything is written, write, read back what they wrote and compare, and end with
//! Update Complete (`20 A8`) so that the node applies the change.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use clap::{Args, Subcommand};
use openlcb_cdi::backup::{self, Snapshot};
use openlcb_cdi::{Entry, EntryKind, Laid, LaidGroup, Layout, Value};
use openlcb_stream::NodeId;
use openlcb_tokio::{Node, TransferPath};
use serde_json::{Value as Json, json};

use crate::cdi::read_cdi;
use crate::memory::{self, ClientArgs, Moved};
use crate::net;
use crate::outcome::{Failure as Stop, Outcome};

/// The fields of `config --json`.
macro_rules! config_json_help {
    () => {
        "\
--json prints one object: node, command, result (the word of the exit status below: \"usage\"
for a value or backup that does not fit the CDI, \"error\" for a CDI that cannot be used,
\"verify_failed\" for a value that reads back differently) and, on failure, error. show adds segments (a tree of groups and entries: key, name, description, type,
space, address, size, value, label, min, max, default, map); get and set add key, value and
label (set also old); backup adds file and entries; restore adds written, unchanged,
unknown_keys, invalid and dry_run. set and restore add warning when the node refused Update
Complete after a verified write (exit status 0: the values are written).

"
    };
}

/// Options of `lcc-stream config`.
#[derive(Debug, Args)]
pub(crate) struct ConfigArgs {
    #[command(subcommand)]
    action: Action,
}

#[derive(Debug, Subcommand)]
enum Action {
    /// Print every setting: the CDI's tree with current values, names, descriptions, map
    /// labels and ranges.
    #[command(after_help = after_help())]
    Show {
        /// The node.
        #[arg(value_name = "NODE_ID", value_parser = crate::args::node_id)]
        node: NodeId,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Print one setting's value, by its key (as `show` and backups name it).
    #[command(after_help = after_help())]
    Get {
        /// The node.
        #[arg(value_name = "NODE_ID", value_parser = crate::args::node_id)]
        node: NodeId,
        /// The key, e.g. "Port I/O.Line(3).Event On".
        key: String,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Set one setting, checked against its type, size, range and map first (a map's label
    /// or its value are both taken).
    #[command(after_help = after_help())]
    Set {
        /// The node.
        #[arg(value_name = "NODE_ID", value_parser = crate::args::node_id)]
        node: NodeId,
        /// The key.
        key: String,
        /// The value: a number (decimal or 0x hex), an Event ID (05.01.01.01.22.F2.00.01),
        /// text, or a label of the entry's map.
        value: String,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Write every int, string and Event ID setting into a file of key=value lines, as JMRI's
    /// Backup does.
    ///
    /// Floats are left out, as JMRI's `BackupConfig` leaves them out (its visitor writes
    /// strings, ints and Event IDs only): the file stays byte for byte JMRI's, and JMRI
    /// restores it. `config show` and `config get` read floats.
    #[command(after_help = after_help())]
    Backup {
        /// The node.
        #[arg(value_name = "NODE_ID", value_parser = crate::args::node_id)]
        node: NodeId,
        /// The file written (never over an existing one) [default: standard output].
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Write a backup (ours or JMRI's) back into a node: only the settings that differ, read
    /// back and compared; keys the CDI does not have are reported, never guessed.
    #[command(after_help = after_help())]
    Restore {
        /// The node.
        #[arg(value_name = "NODE_ID", value_parser = crate::args::node_id)]
        node: NodeId,
        /// The backup file.
        file: PathBuf,
        /// Show what would be written, write nothing.
        #[arg(long)]
        dry_run: bool,
        #[command(flatten)]
        client: ClientArgs,
    },
}

/// The after-help of every `config` command: its JSON fields and its exit statuses.
fn after_help() -> String {
    let outcomes = [
        Outcome::Usage,
        Outcome::Rejected,
        Outcome::TimedOut,
        Outcome::NotFound,
        Outcome::Terminated,
        Outcome::FileError,
        Outcome::VerifyFailed,
        Outcome::BadAnswer,
    ];
    let cdi = crate::cdi::cdi_help();
    format!("{}{cdi}{}{}", config_json_help!(), crate::pace::PACE_HELP, net::network_help(&outcomes))
}

/// Why a config command stopped (also an operation of `ui`).
pub(crate) enum Failure {
    /// Joining, reading, writing or a file.
    Stop(Stop),
    /// The node's CDI cannot be used.
    Cdi(openlcb_cdi::Error),
    /// A value or a backup does not fit the CDI: nothing was written.
    Invalid(String),
    /// What was read back is not what was written.
    Verify(String),
    /// A restore stopped by `cause` after `written` of its `of` settings were written.
    Partial { cause: Box<Failure>, written: usize, of: usize },
}

impl From<Stop> for Failure {
    fn from(stop: Stop) -> Self {
        Failure::Stop(stop)
    }
}

impl Failure {
    pub(crate) fn outcome(&self) -> Outcome {
        match self {
            Failure::Stop(stop) => stop.outcome(),
            Failure::Cdi(_) => Outcome::Error,
            Failure::Invalid(_) => Outcome::Usage,
            Failure::Verify(_) => Outcome::VerifyFailed,
            Failure::Partial { cause, .. } => cause.outcome(),
        }
    }
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::Stop(stop) => write!(f, "{stop}"),
            Failure::Cdi(error) => write!(f, "the node's CDI: {error}"),
            Failure::Invalid(text) | Failure::Verify(text) => f.write_str(text),
            Failure::Partial { cause, written, of } => write!(
                f,
                "{cause}: {written} of {of} settings were written before it stopped; \
                 `config restore` again writes the rest"
            ),
        }
    }
}

/// A command's result: the text for a person and the fields for `--json`.
pub(crate) struct Done {
    pub(crate) text: String,
    pub(crate) fields: Json,
    /// What went wrong after the work was done (Update Complete refused): printed, and in
    /// `--json` as `warning`, with exit status 0.
    pub(crate) warning: Option<String>,
}

pub(crate) fn run(args: &ConfigArgs) -> Result<ExitCode, String> {
    let (node, client, name) = match &args.action {
        Action::Show { node, client } => (*node, client, "show"),
        Action::Get { node, client, .. } => (*node, client, "get"),
        Action::Set { node, client, .. } => (*node, client, "set"),
        Action::Backup { node, client, .. } => (*node, client, "backup"),
        Action::Restore { node, client, .. } => (*node, client, "restore"),
    };
    let outcome = net::runtime()?.block_on(async {
        let mut interrupt = net::Interrupt::new().map_err(|e| Failure::Invalid(e.to_string()))?;
        if let Action::Backup { out: Some(out), .. } = &args.action {
            memory::refuse_existing(out).await?;
        }
        let joined = memory::join(client, "config", node).await?;
        let done = async {
            let session = Session::open(&joined, client, node, &mut interrupt).await?;
            let done = session.act(&args.action, &mut interrupt).await?;
            if let Action::Backup { out: Some(out), .. } = &args.action {
                memory::save_new(out, done.text.as_bytes()).await?;
            }
            Ok(done)
        }
        .await;
        joined.close().await;
        done
    });
    Ok(finish(node, name, client.json, outcome, &args.action))
}

/// Prints the result (text or JSON) and returns the exit status.
fn finish(node: NodeId, command: &str, json: bool, outcome: Result<Done, Failure>, action: &Action) -> ExitCode {
    let mut object = json!({ "node": node.to_string(), "command": command });
    let status = match outcome {
        Ok(done) => {
            if !json {
                match action {
                    Action::Backup { out: Some(out), .. } => outln!("backed up {} into {}", node, out.display()),
                    _ => out!("{}", done.text),
                }
            }
            if let Some(warning) = &done.warning {
                eprintln!("lcc-stream config {command}: warning: {warning}");
                object["warning"] = json!(warning);
            }
            merge(&mut object, done.fields);
            object["result"] = json!("ok");
            0
        }
        Err(failure) => {
            if !json {
                eprintln!("lcc-stream config {command}: {failure}");
            }
            object["result"] = json!(failure.outcome().word());
            object["error"] = json!(failure.to_string());
            failure.outcome().status()
        }
    };
    if json {
        net::print_json(&object);
    }
    ExitCode::from(status)
}

fn merge(object: &mut Json, fields: Json) {
    if let (Some(object), Json::Object(fields)) = (object.as_object_mut(), fields) {
        object.extend(fields);
    }
}

/// A joined client node, the target and its laid-out CDI.
pub(crate) struct Session<'a> {
    node: &'a Node,
    peer: NodeId,
    client: &'a ClientArgs,
    layout: Arc<Layout>,
}

/// `peer`'s CDI, read by `node` and laid out.
pub(crate) async fn read_layout(
    node: &Node,
    peer: NodeId,
    client: &ClientArgs,
    interrupt: &mut net::Interrupt,
) -> Result<Layout, Failure> {
    let xml = read_cdi(node, peer, client, interrupt, &mut Moved::default()).await?;
    match std::str::from_utf8(&xml) {
        Ok(xml) => Layout::parse(xml).map_err(Failure::Cdi),
        Err(_) => Err(Failure::Cdi(openlcb_cdi::Error::Xml { line: 0, column: 0 })),
    }
}

impl<'a> Session<'a> {
    /// Reads `peer`'s CDI through `node`, which stays open when this ends.
    async fn open(
        node: &'a Node,
        client: &'a ClientArgs,
        peer: NodeId,
        interrupt: &mut net::Interrupt,
    ) -> Result<Session<'a>, Failure> {
        let layout = read_layout(node, peer, client, interrupt).await?;
        Ok(Session { node, peer, client, layout: Arc::new(layout) })
    }

    /// A session on `peer` whose CDI was read already.
    pub(crate) fn with_layout(node: &'a Node, client: &'a ClientArgs, peer: NodeId, layout: Arc<Layout>) -> Self {
        Session { node, peer, client, layout }
    }

    /// `config show` (the tree with every value, as JSON in `fields`).
    pub(crate) async fn show(&self, interrupt: &mut net::Interrupt) -> Result<Done, Failure> {
        let snapshot = self.read_spans(interrupt).await?;
        show(&self.layout, &snapshot)
    }

    /// `config backup`: the file's text.
    pub(crate) async fn backup(&self, interrupt: &mut net::Interrupt) -> Result<String, Failure> {
        let snapshot = self.read_spans(interrupt).await?;
        backup::write(&self.layout, &snapshot).map_err(Failure::Cdi)
    }

    /// Writes `changes` (key and value as `config set` takes them), each checked first (a
    /// bad one writes nothing), only those that differ from what the node holds, by runs of
    /// neighbours, each read back and compared, then Update Complete: the keys written.
    pub(crate) async fn set_many(
        &self,
        changes: &[(String, String)],
        interrupt: &mut net::Interrupt,
    ) -> Result<(Vec<String>, Option<String>), Failure> {
        let mut checked = Vec::with_capacity(changes.len());
        for (key, text) in changes {
            let entry = self.entry(key)?;
            let (value, bytes) = entry.parse_strict(text).map_err(|e| Failure::Invalid(format!("{key}: {e}")))?;
            checked.push((entry, value, bytes));
        }
        if checked.is_empty() {
            return Ok((Vec::new(), None));
        }
        let snapshot = self.read_spans(interrupt).await?;
        let mut writes = Vec::new();
        for (entry, new, bytes) in checked {
            let old = snapshot.value(entry).map_err(Failure::Cdi)?;
            if old != new {
                writes.push(backup::Change { entry: entry.clone(), old, new, bytes });
            }
        }
        self.write_changes(&writes, interrupt).await?;
        let warning = if writes.is_empty() { None } else { self.update_complete(interrupt).await? };
        Ok((writes.iter().map(|c| c.entry.key.clone()).collect(), warning))
    }

    /// Writes `writes` by runs of neighbours, each verified; the count written.
    async fn write_changes(&self, writes: &[backup::Change], interrupt: &mut net::Interrupt) -> Result<(), Failure> {
        let mut written = 0;
        for (space, address, bytes) in backup::coalesce(writes) {
            let mut moved = Moved::default();
            let len = bytes.len() as u64;
            let result = self.write_verified((space, address), bytes, interrupt, &mut moved).await;
            // A stopped write took its first `moved.bytes` bytes: the settings inside them.
            let took = if result.is_ok() { len } else { moved.bytes };
            written += settings_within(writes, (space, address), took);
            if let Err(cause) = result {
                return Err(Failure::Partial { cause: Box::new(cause), written, of: writes.len() });
            }
        }
        Ok(())
    }

    /// The plan of a restore of `text` (a backup's): refused, as `config restore` refuses it,
    /// when a line is given twice or a value does not fit.
    pub(crate) async fn restore_plan(
        &self,
        text: &str,
        interrupt: &mut net::Interrupt,
    ) -> Result<backup::Plan, Failure> {
        let lines = backup::parse(text).map_err(|e| Failure::Invalid(format!("the backup: {e}")))?;
        let snapshot = self.read_spans(interrupt).await?;
        let plan = backup::plan(&self.layout, &snapshot, &lines).map_err(Failure::Cdi)?;
        refuse_bad_plan(&plan, "the backup")?;
        Ok(plan)
    }

    /// Writes a plan's changes, verified, then Update Complete (the warning if it failed).
    pub(crate) async fn apply(
        &self,
        plan: &backup::Plan,
        interrupt: &mut net::Interrupt,
    ) -> Result<Option<String>, Failure> {
        if plan.writes.is_empty() {
            return Ok(None);
        }
        self.write_changes(&plan.writes, interrupt).await?;
        self.update_complete(interrupt).await
    }

    async fn act(&self, action: &Action, interrupt: &mut net::Interrupt) -> Result<Done, Failure> {
        match action {
            Action::Show { .. } => {
                let snapshot = self.read_spans(interrupt).await?;
                show(&self.layout, &snapshot)
            }
            Action::Get { key, .. } => {
                let entry = self.entry(key)?;
                let value = self.read_value(entry, interrupt).await?;
                let label = entry.label(&value).map(str::to_string);
                let text = format!("{value}\n");
                Ok(Done {
                    text,
                    fields: json!({ "key": key, "value": value_json(&value), "label": label }),
                    warning: None,
                })
            }
            Action::Set { key, value, .. } => self.set(key, value, interrupt).await,
            Action::Backup { .. } => {
                let snapshot = self.read_spans(interrupt).await?;
                let text = backup::write(&self.layout, &snapshot).map_err(Failure::Cdi)?;
                let entries = text.lines().count();
                let file = match action {
                    Action::Backup { out: Some(out), .. } => out.display().to_string(),
                    _ => "-".to_string(),
                };
                Ok(Done { text, fields: json!({ "file": file, "entries": entries }), warning: None })
            }
            Action::Restore { file, dry_run, .. } => self.restore(file, *dry_run, interrupt).await,
        }
    }

    /// The one entry named `key`.
    fn entry(&self, key: &str) -> Result<&Entry, Failure> {
        let found: Vec<&Entry> = self.layout.entries().filter(|e| e.key == key).collect();
        match found.as_slice() {
            [entry] => Ok(entry),
            [_, _, ..] => Err(Failure::Invalid(format!("the CDI has several entries named {key}"))),
            [] => Err(Failure::Invalid(format!("the CDI has no entry {key} (`config show` lists them)"))),
        }
    }

    async fn read(
        &self,
        space: u8,
        address: u32,
        len: u32,
        interrupt: &mut net::Interrupt,
    ) -> Result<Vec<u8>, Failure> {
        let transfer =
            self.node.read_memory(self.peer, space, address, Some(len), self.path(len)).await.map_err(Stop::Net)?;
        let moved = &mut Moved::default();
        Ok(memory::follow(
            self.node,
            transfer,
            Some(u64::from(len)),
            self.client.json,
            &self.client.pace,
            interrupt,
            moved,
        )
        .await?)
    }

    /// Small transfers by datagrams (no Options round trip), the rest as the user asked.
    fn path(&self, len: u32) -> TransferPath {
        if len <= 128 { TransferPath::Datagrams } else { self.client.path() }
    }

    /// Every segment's span, one read each.
    async fn read_spans(&self, interrupt: &mut net::Interrupt) -> Result<Snapshot, Failure> {
        let mut snapshot = Snapshot::new();
        for span in self.layout.spans() {
            let bytes = self.read(span.space, span.address, span.len, interrupt).await?;
            snapshot.insert(span, bytes);
        }
        Ok(snapshot)
    }

    async fn read_value(&self, entry: &Entry, interrupt: &mut net::Interrupt) -> Result<Value, Failure> {
        let bytes = self.read(entry.space, entry.address, entry.size, interrupt).await?;
        entry.decode(&bytes).map_err(|error| Failure::Cdi(openlcb_cdi::Error::Value { key: entry.key.clone(), error }))
    }

    /// Writes `bytes` at `address`, reads them back and compares; `moved` counts the bytes
    /// the node took (also when it stops early).
    async fn write_verified(
        &self,
        (space, address): (u8, u32),
        bytes: Vec<u8>,
        interrupt: &mut net::Interrupt,
        moved: &mut Moved,
    ) -> Result<(), Failure> {
        let len = bytes.len() as u32;
        let transfer = self
            .node
            .write_memory(self.peer, space, address, bytes.clone(), self.path(len))
            .await
            .map_err(Stop::Net)?;
        memory::follow(
            self.node,
            transfer,
            Some(u64::from(len)),
            self.client.json,
            &self.client.pace,
            interrupt,
            moved,
        )
        .await?;
        let back = self.read(space, address, len, interrupt).await?;
        if back != bytes {
            return Err(Failure::Verify(format!(
                "space 0x{space:02X} at {address} reads back differently from what was written ({len} bytes)"
            )));
        }
        Ok(())
    }

    /// Update Complete after a verified write: a node that refuses it or does not answer
    /// still holds what was written, so that is a warning (None: it said OK).
    async fn update_complete(&self, interrupt: &mut net::Interrupt) -> Result<Option<String>, Failure> {
        match memory::update_complete(self.node, self.peer, &self.client.pace, interrupt).await {
            Err(Stop::Interrupted) => Err(Failure::Stop(Stop::Interrupted)),
            Err(stop) => Ok(Some(memory::update_complete_warning(&stop))),
            Ok(()) => Ok(None),
        }
    }

    async fn set(&self, key: &str, text: &str, interrupt: &mut net::Interrupt) -> Result<Done, Failure> {
        let entry = self.entry(key)?;
        let (value, bytes) = entry.parse_strict(text).map_err(|e| Failure::Invalid(format!("{key}: {e}")))?;
        let old = self.read_value(entry, interrupt).await?;
        self.write_verified((entry.space, entry.address), bytes, interrupt, &mut Moved::default()).await?;
        let warning = self.update_complete(interrupt).await?;
        let label = entry.label(&value).map(str::to_string);
        let shown = label.as_ref().map_or(value.to_string(), |l| format!("{value} ({l})"));
        Ok(Done {
            text: format!("{key} = {shown} (was {old})\n"),
            fields: json!({ "key": key, "value": value_json(&value), "label": label, "old": value_json(&old) }),
            warning,
        })
    }

    async fn restore(
        &self,
        file: &std::path::Path,
        dry_run: bool,
        interrupt: &mut net::Interrupt,
    ) -> Result<Done, Failure> {
        let text = read_backup(file, backup::max_backup_bytes(&self.layout)).await?;
        let lines = backup::parse(&text).map_err(|e| Failure::Invalid(format!("{}: {e}", file.display())))?;
        let snapshot = self.read_spans(interrupt).await?;
        let plan = backup::plan(&self.layout, &snapshot, &lines).map_err(Failure::Cdi)?;
        refuse_bad_plan(&plan, &file.display().to_string())?;
        let mut out = String::new();
        for change in &plan.writes {
            let verb = if dry_run { "would set" } else { "set" };
            out.push_str(&format!("{verb} {} = {} (was {})\n", change.entry.key, change.new, change.old));
        }
        for key in &plan.unknown_keys {
            out.push_str(&format!("not in the CDI, left alone: {key}\n"));
        }
        let mut warning = None;
        if !dry_run && !plan.writes.is_empty() {
            self.write_changes(&plan.writes, interrupt).await?;
            warning = self.update_complete(interrupt).await?;
        }
        out.push_str(&format!(
            "{} {} of {} settings ({} unchanged, {} not in the CDI)\n",
            if dry_run { "would write" } else { "wrote" },
            plan.writes.len(),
            lines.len(),
            plan.unchanged,
            plan.unknown_keys.len()
        ));
        let written: Vec<&str> = plan.writes.iter().map(|c| c.entry.key.as_str()).collect();
        Ok(Done {
            text: out,
            fields: json!({
                "written": written,
                "unchanged": plan.unchanged,
                "unknown_keys": plan.unknown_keys,
                "invalid": [],
                "dry_run": dry_run,
            }),
            warning,
        })
    }
}

/// Refuses a plan with a setting given twice or a value that does not fit (`file` names the
/// backup): nothing is written.
fn refuse_bad_plan(plan: &backup::Plan, file: &str) -> Result<(), Failure> {
    if !plan.duplicates.is_empty() {
        let lines: Vec<String> = plan
            .duplicates
            .iter()
            .map(|d| format!("{} on line {} and again on line {}", d.key, d.first_line, d.line))
            .collect();
        return Err(Failure::Invalid(format!("nothing written; {file}: a setting given twice: {}", lines.join("; "))));
    }
    if !plan.invalid.is_empty() {
        let reasons: Vec<String> = plan.invalid.iter().map(|(key, e)| format!("{key}: {e}")).collect();
        return Err(Failure::Invalid(format!("nothing written; the backup does not fit: {}", reasons.join("; "))));
    }
    Ok(())
}

/// How many of `changes` lie wholly in the `len` bytes from `address` of `space`.
fn settings_within(changes: &[backup::Change], (space, address): (u8, u32), len: u64) -> usize {
    let end = u64::from(address) + len;
    let inside = |c: &&backup::Change| {
        let start = u64::from(c.entry.address);
        c.entry.space == space && start >= u64::from(address) && start + c.bytes.len() as u64 <= end
    };
    changes.iter().filter(inside).count()
}

/// The text of a backup file, refused unread past `max_bytes` (more than the node's CDI can
/// hold: not a backup of this node).
async fn read_backup(file: &std::path::Path, max_bytes: usize) -> Result<String, Failure> {
    use tokio::io::AsyncReadExt as _;
    let opened = tokio::fs::File::open(file).await.map_err(|e| Failure::Stop(Stop::file(file, e)))?;
    let mut bytes = Vec::new();
    let limit = u64::try_from(max_bytes).unwrap_or(u64::MAX).saturating_add(1);
    opened.take(limit).read_to_end(&mut bytes).await.map_err(|e| Failure::Stop(Stop::file(file, e)))?;
    if bytes.len() > max_bytes {
        return Err(Failure::Invalid(format!(
            "nothing written; {} is larger than a backup of this node's CDI can be ({max_bytes} bytes)",
            file.display()
        )));
    }
    String::from_utf8(bytes).map_err(|e| Failure::Invalid(format!("{}: not UTF-8 text ({e})", file.display())))
}

/// A value as `--json` prints it.
pub(crate) fn value_json(value: &Value) -> Json {
    match value {
        Value::Int(v) => json!(v),
        Value::Float(v) => json!(v),
        other => json!(other.to_string()),
    }
}

/// `config show`: the tree as text and as JSON.
fn show(layout: &Layout, snapshot: &Snapshot) -> Result<Done, Failure> {
    let mut text = String::new();
    let mut segments = Vec::new();
    for segment in &layout.segments {
        let origin = u32::try_from(segment.address).unwrap_or_default();
        text.push_str(&format!(
            "{} (space 0x{:02X} from {origin})\n",
            segment.label.as_deref().unwrap_or(&segment.key),
            segment.space
        ));
        describe(&mut text, segment.description.as_deref(), 1);
        segments.push(group_json(segment, snapshot, &mut text, 1)?);
    }
    Ok(Done { text, fields: json!({ "segments": segments }), warning: None })
}

fn describe(text: &mut String, description: Option<&str>, depth: usize) {
    if let Some(description) = description.map(str::trim).filter(|d| !d.is_empty()) {
        for line in description.lines() {
            text.push_str(&format!("{}# {}\n", "  ".repeat(depth), line.trim()));
        }
    }
}

fn group_json(group: &LaidGroup, snapshot: &Snapshot, text: &mut String, depth: usize) -> Result<Json, Failure> {
    let mut children = Vec::new();
    for child in &group.children {
        match child {
            Laid::Group(inner) => {
                text.push_str(&format!("{}{}\n", "  ".repeat(depth), inner.label.as_deref().unwrap_or(&inner.key)));
                describe(text, inner.description.as_deref(), depth + 1);
                children.push(group_json(inner, snapshot, text, depth + 1)?);
            }
            Laid::Entry(entry) => children.push(entry_json(entry, snapshot, text, depth)?),
        }
    }
    Ok(json!({
        "key": group.key,
        "name": group.label,
        "description": group.description,
        "space": group.space,
        "address": group.address,
        "size": group.size,
        "children": children,
    }))
}

fn entry_json(entry: &Entry, snapshot: &Snapshot, text: &mut String, depth: usize) -> Result<Json, Failure> {
    let value = match entry.kind {
        EntryKind::Action { .. } | EntryKind::Unknown => None,
        _ => Some(snapshot.value(entry).map_err(Failure::Cdi)?),
    };
    let label = value.as_ref().and_then(|v| entry.label(v)).map(str::to_string);
    let (min, max, default) = match &entry.kind {
        EntryKind::Int { min, max, default } => {
            (min.map(|v| json!(v)), max.map(|v| json!(v)), default.map(|v| json!(v)))
        }
        EntryKind::Float { min, max, default } => {
            (min.map(|v| json!(v)), max.map(|v| json!(v)), default.map(|v| json!(v)))
        }
        _ => (None, None, None),
    };
    let mut line = format!("{}{}", "  ".repeat(depth), entry.name.as_deref().unwrap_or(&entry.key));
    match (&value, &label) {
        (Some(Value::String(s)), _) => line.push_str(&format!(" = {s:?}")),
        (Some(v), Some(l)) => line.push_str(&format!(" = {l} ({v})")),
        (Some(v), None) => line.push_str(&format!(" = {v}")),
        (None, _) => line.push_str(&format!(" [{}]", entry.kind.word())),
    }
    let mut notes = Vec::new();
    if min.is_some() || max.is_some() {
        let bound = |b: &Option<Json>| b.as_ref().map_or(String::new(), Json::to_string);
        notes.push(format!("{}..{}", bound(&min), bound(&max)));
    }
    if let Some(default) = &default {
        notes.push(format!("default {default}"));
    }
    if !entry.map.is_empty() {
        let choices: Vec<String> = entry.map.relations.iter().map(|(p, v)| format!("{p}={v}")).collect();
        notes.push(choices.join(", "));
    }
    if !notes.is_empty() {
        line.push_str(&format!("  ({})", notes.join("; ")));
    }
    text.push_str(&line);
    text.push_str(&format!("  [{}]\n", entry.key));
    describe(text, entry.description.as_deref(), depth + 1);
    let map: Vec<Json> = entry.map.relations.iter().map(|(p, v)| json!({ "value": p, "label": v })).collect();
    Ok(json!({
        "key": entry.key,
        "name": entry.name,
        "description": entry.description,
        "type": entry.kind.word(),
        "space": entry.space,
        "address": entry.address,
        "size": entry.size,
        "value": value.as_ref().map(value_json),
        "label": label,
        "min": min,
        "max": max,
        "default": default,
        "map": map,
    }))
}
