//! `lcc-stream nodes` against a real hub on 127.0.0.1 with two nodes on it, one over
//! GridConnect and one over OpenLCB-TCP (through the hub's bridge): both are listed with their
//! SNIP strings and protocols, as text and as JSON.

mod common;

use common::{bounded, command};
use openlcb_tokio::{Framing, Hub, HubOptions, Node, NodeId, NodeOptions, SnipInfo};

fn options(id: &str, model: &str, name: &str) -> NodeOptions {
    let mut options = NodeOptions::new(id.parse::<NodeId>().unwrap());
    options.node.snip = SnipInfo {
        manufacturer: "Acme".into(),
        model: model.into(),
        hardware_version: "1.0".into(),
        software_version: "2.3".into(),
        user_name: name.into(),
        user_description: "West end".into(),
    };
    options
}

async fn nodes(args: &[&str]) -> (i32, String) {
    let child = command(&[&["nodes"], args].concat()).spawn().unwrap();
    let output = bounded("nodes", child.wait_with_output()).await.unwrap();
    (output.status.code().unwrap_or(-1), String::from_utf8_lossy(&output.stdout).into_owned())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nodes_lists_every_node_with_its_snip_and_protocols() {
    let hub = Hub::bind("127.0.0.1:0", Some("127.0.0.1:0"), HubOptions::default()).await.unwrap();
    let gridconnect = hub.local_addr().to_string();
    let tcp = hub.tcp_local_addr().unwrap().to_string();
    let yard = Node::connect(&gridconnect, Framing::GridConnect, options("05.01.01.01.40.01", "Widget", "Yard"))
        .await
        .unwrap();
    let shed = Node::connect(&tcp, Framing::Tcp, options("05.01.01.01.40.02", "Gadget", "Shed")).await.unwrap();

    let (status, json) = nodes(&["--connect", &gridconnect, "--json", "--wait", "0.5"]).await;
    assert_eq!(status, 0, "{json}");
    let mut listed: Vec<serde_json::Value> = json.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    listed.sort_by_key(|n| n["node_id"].as_str().unwrap().to_string());
    assert_eq!(listed.len(), 2, "{json}");
    assert_eq!(listed[0]["node_id"], "05.01.01.01.40.01");
    assert_eq!(listed[0]["snip"]["model"], "Widget");
    assert_eq!(listed[0]["snip"]["user_name"], "Yard");
    assert_eq!(listed[0]["alias"].as_str().map(str::len), Some(3), "a CAN node has an alias");
    assert_eq!(listed[1]["node_id"], "05.01.01.01.40.02");
    assert_eq!(listed[1]["snip"]["model"], "Gadget");
    assert_eq!(listed[1]["snip"]["user_description"], "West end");
    for node in &listed {
        let protocols: Vec<&str> = node["protocols"].as_array().unwrap().iter().map(|p| p.as_str().unwrap()).collect();
        assert_eq!(protocols, ["Datagram", "Stream", "SNIP"], "{node}");
        assert_eq!(node["errors"].as_array().map(Vec::len), Some(0), "{node}");
    }

    // The same over OpenLCB-TCP, as text: one line a node.
    let (status, text) = nodes(&["--connect", &tcp, "--protocol", "tcp", "--wait", "0.5"]).await;
    assert_eq!(status, 0);
    let mut lines: Vec<&str> = text.lines().collect();
    lines.sort();
    assert_eq!(lines.len(), 2, "{text}");
    assert!(lines[0].starts_with("05.01.01.01.40.01") && lines[0].contains("Acme Widget (hw 1.0, sw 2.3)"), "{text}");
    assert!(lines[1].contains("\"Shed\"  West end  [Datagram Stream SNIP]"), "{text}");
    drop((yard, shed));
}

#[tokio::test]
async fn nodes_refuses_a_wait_out_of_range() {
    let (status, _) = nodes(&["--wait", "0"]).await;
    assert_eq!(status, 2);
}
