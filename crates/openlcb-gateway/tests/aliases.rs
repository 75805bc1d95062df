//! Alias login, defence and resolution on behalf of full-format nodes, and what is not
//! forwarded.

mod common;

use common::{CAN_NODE, FULL_NODE, Net, core_config, node_id};
use openlcb_can::{CanFrame, NodeAlias};
use openlcb_gateway::{GatewayConfig, GatewayEvent};
use openlcb_stream::{Duration, Instant, Message, Mti};

const STRANGER: u64 = 0x0501_0101_2277;

fn started() -> Net {
    Net::started(GatewayConfig::default(), core_config(256), core_config(256))
}

fn frame(id: u32, data: &[u8]) -> CanFrame {
    CanFrame::extended(id, data).unwrap()
}

fn proxy_alias(net: &Net) -> NodeAlias {
    net.gateway.proxy_alias(node_id(FULL_NODE)).unwrap()
}

/// The frames the gateway sent since `from`, as (identifier without the alias, alias).
fn sent_since(net: &Net, from: usize) -> Vec<(u32, u16)> {
    net.from_gateway[from..].iter().map(|f| (f.raw_id() & 0x1FFF_F000, (f.raw_id() & 0xFFF) as u16)).collect()
}

#[test]
fn proxied_node_logs_in_before_its_first_message() {
    let mut net = Net::new(GatewayConfig::default(), core_config(256), core_config(256));
    net.settle();
    // The full node's Initialization Complete made the gateway start a login for it.
    let cids = sent_since(&net, 0);
    assert_eq!(cids.iter().map(|c| c.0 >> 24).collect::<Vec<_>>(), [0x17, 0x16, 0x15, 0x14]);
    let alias = cids[0].1;
    assert!(cids.iter().all(|c| c.1 == alias));
    let full = node_id(FULL_NODE).as_raw();
    let carried: u64 = cids.iter().map(|c| u64::from((c.0 >> 12) & 0xFFF)).fold(0, |acc, bits| acc << 12 | bits);
    assert_eq!(carried, full, "CID 7..4 carry the proxied Node ID");
    assert!(net.to_full.is_empty() || net.to_full.iter().all(|m| m.mti != Mti::INITIALIZATION_COMPLETE));

    net.advance_to(Instant::from_millis(200));
    net.settle();
    let after = sent_since(&net, 4);
    assert_eq!(
        after[..3],
        [(0x1070_0000, alias), (0x1070_1000, alias), (0x1910_0000, alias)],
        "RID, AMD, then the message"
    );
    assert_eq!(net.from_gateway[5].payload(), node_id(FULL_NODE).to_bytes(), "AMD carries the Node ID");
    assert_eq!(net.can_link.node_of(NodeAlias::new(alias).unwrap()), Some(node_id(FULL_NODE)));
    assert!(
        net.gateway_events.contains(&GatewayEvent::ProxyPermitted {
            node: node_id(FULL_NODE),
            alias: NodeAlias::new(alias).unwrap()
        })
    );
}

#[test]
fn proxied_alias_is_defended_against_cid_and_answers_ame() {
    let mut net = started();
    let alias = proxy_alias(&net);
    let ours = u32::from(alias.as_raw());
    let before = net.from_gateway.len();
    let enquiries = [
        frame(0x1712_3000 | ours, &[]), // CID with our alias
        frame(0x1070_2ABC, &[]),        // global AME
        frame(0x1070_2ABC, &node_id(FULL_NODE).to_bytes()),
        frame(0x1070_2ABC, &node_id(STRANGER).to_bytes()),
    ];
    for enquiry in enquiries {
        net.gateway.handle_can_frame(net.now, &enquiry);
        net.settle();
    }
    let sent = sent_since(&net, before);
    assert_eq!(sent, [(0x1070_0000, alias.as_raw()), (0x1070_1000, alias.as_raw()), (0x1070_1000, alias.as_raw())]);
    assert_eq!(proxy_alias(&net), alias, "the alias is kept");
}

#[test]
fn collision_on_a_proxied_alias_releases_it_and_logs_in_again() {
    let mut net = started();
    let alias = proxy_alias(&net);
    let before = net.from_gateway.len();
    // Another node sends a message from our alias.
    let ours = u32::from(alias.as_raw());
    net.gateway.handle_can_frame(net.now, &frame(0x1917_0000 | ours, &node_id(STRANGER).to_bytes()));
    net.settle();
    let sent = sent_since(&net, before);
    assert_eq!(sent[0], (0x1070_3000, alias.as_raw()), "AMR first");
    assert_eq!(net.from_gateway[before].payload(), node_id(FULL_NODE).to_bytes());
    let new_alias = sent[1].1;
    assert_ne!(new_alias, alias.as_raw());
    assert_eq!(sent[1..].iter().map(|s| s.0 >> 24).collect::<Vec<_>>(), [0x17, 0x16, 0x15, 0x14]);
    assert!(net.gateway_events.contains(&GatewayEvent::ProxyAliasLost { node: node_id(FULL_NODE), alias }));

    // Messages from the node wait for the new alias.
    let verify = Message::global(Mti::VERIFY_NODE_ID_GLOBAL, node_id(FULL_NODE), &[][..]);
    net.gateway.handle_message(net.now, verify.as_ref());
    net.settle();
    assert_eq!(net.from_gateway.len(), before + 5, "nothing but the login until permitted");
    net.advance_to(net.now + Duration::from_millis(200));
    net.settle();
    let sent = sent_since(&net, before + 5);
    assert_eq!(sent[..3], [(0x1070_0000, new_alias), (0x1070_1000, new_alias), (0x1949_0000, new_alias)]);
}

#[test]
fn unknown_destination_is_asked_for_and_dropped_after_the_timeout() {
    let mut net = started();
    let alias = proxy_alias(&net);
    let stranger = node_id(STRANGER);
    let verify = Message::addressed(Mti::VERIFY_NODE_ID_ADDRESSED, node_id(FULL_NODE), stranger, &[][..]);
    let before = net.from_gateway.len();
    net.gateway.handle_message(net.now, verify.as_ref());
    net.settle();
    assert_eq!(sent_since(&net, before), [(0x1070_2000, alias.as_raw())], "AME");
    assert_eq!(net.from_gateway[before].payload(), stranger.to_bytes());
    net.advance_to(net.now + Duration::from_secs(1));
    net.settle();
    assert!(net.gateway_events.contains(&GatewayEvent::Unreachable { node: stranger, dropped: 1 }));
    assert_eq!(net.from_gateway.len(), before + 1, "the message was dropped");
    assert_eq!(net.gateway.stats().unresolved_dropped, 1);

    // Asked again, and this time the node answers.
    net.gateway.handle_message(net.now, verify.as_ref());
    net.settle();
    net.gateway.handle_can_frame(net.now, &frame(0x1070_1777, &stranger.to_bytes()));
    net.settle();
    let sent = sent_since(&net, before + 1);
    assert_eq!(sent, [(0x1070_2000, alias.as_raw()), (0x1948_8000, alias.as_raw())]);
    assert_eq!(net.from_gateway.last().unwrap().payload(), [0x07, 0x77], "addressed to the learned alias");
}

#[test]
fn special_mtis_are_not_forwarded() {
    let mut net = started();
    let (before_can, before_full) = (net.from_gateway.len(), net.to_full.len());
    let special = Message::addressed(Mti(0x2DA8), node_id(FULL_NODE), node_id(CAN_NODE), &[1, 2][..]);
    let too_long = Message::addressed(Mti::DATAGRAM, node_id(FULL_NODE), node_id(CAN_NODE), vec![0u8; 73]);
    net.gateway.handle_message(net.now, special.as_ref());
    net.gateway.handle_message(net.now, too_long.as_ref());
    net.settle();
    assert_eq!((net.from_gateway.len(), net.to_full.len()), (before_can, before_full));
    let stats = net.gateway.stats();
    assert_eq!((stats.not_forwardable, stats.datagrams_forwarded), (2, 0));
}

#[test]
fn traffic_between_nodes_of_one_side_stays_there() {
    let mut net = started();
    let before = net.to_full.len();
    // The CAN node asks another CAN node (alias 0x777) something.
    let can_alias = u32::from(net.can_link.alias().unwrap().as_raw());
    net.gateway.handle_can_frame(net.now, &frame(0x1948_8000 | can_alias, &[0x07, 0x77]));
    net.settle();
    assert_eq!(net.to_full.len(), before);
    assert_eq!(net.gateway.stats().stayed_local, 1);
}

#[test]
fn another_node_with_the_proxied_node_id_makes_the_proxy_release_its_alias_and_go_quiet() {
    let mut net = started();
    let before = net.from_gateway.len();
    net.gateway.handle_can_frame(net.now, &frame(0x1070_1777, &node_id(FULL_NODE).to_bytes()));
    let verify = Message::global(Mti::VERIFY_NODE_ID_GLOBAL, node_id(FULL_NODE), &[][..]);
    net.gateway.handle_message(net.now, verify.as_ref());
    net.settle();
    assert!(net.gateway_events.iter().any(|e| matches!(e, GatewayEvent::DuplicateNodeId { .. })));
    let sent: Vec<u32> = net.from_gateway[before..].iter().map(|f| f.raw_id() & !0xFFF).collect();
    assert_eq!(sent, [0x1070_3000], "AMR for the proxy's alias, then nothing more for the node");
    assert_eq!(net.gateway.stats().lost_with_alias, 1);
}

#[test]
fn full_proxy_table_releases_the_least_recently_used_idle_alias() {
    let mut config = GatewayConfig::default();
    config.max_proxied_nodes = 1;
    let mut net = Net::started(config, core_config(256), core_config(256));
    let old = proxy_alias(&net);
    let before = net.from_gateway.len();
    let other = Message::global(Mti::VERIFY_NODE_ID_GLOBAL, node_id(STRANGER), &[][..]);
    net.gateway.handle_message(net.now, other.as_ref());
    net.settle();
    let sent = sent_since(&net, before);
    // The new node's check starts at once; the evicted node's AMR follows.
    assert_eq!(sent[..4].iter().map(|s| s.0 >> 24).collect::<Vec<_>>(), [0x17, 0x16, 0x15, 0x14]);
    assert_eq!(sent[4..], [(0x1070_3000, old.as_raw())], "AMR for the evicted node");
    assert_eq!(net.gateway.proxy_alias(node_id(FULL_NODE)), None);
}

#[test]
fn a_full_node_that_left_releases_its_alias_and_its_node_id_may_join_on_can() {
    let mut net = started();
    let alias = proxy_alias(&net);
    let before = net.from_gateway.len();
    net.gateway.handle_full_node_left(net.now, node_id(FULL_NODE));
    net.settle();
    assert_eq!(sent_since(&net, before), [(0x1070_3000, alias.as_raw())], "one AMR for the proxy's alias");
    assert_eq!(net.from_gateway[before].payload(), node_id(FULL_NODE).to_bytes(), "AMR carries the Node ID");
    assert_eq!(net.gateway.proxy_alias(node_id(FULL_NODE)), None);
    assert!(net.gateway_events.contains(&GatewayEvent::ProxyReleased { node: node_id(FULL_NODE), alias: Some(alias) }));
    // The same Node ID logs in on CAN under another alias: learned as a CAN node, no duplicate.
    let newcomer = NodeAlias::new(0x777).unwrap();
    let after = net.from_gateway.len();
    net.gateway.handle_can_frame(net.now, &frame(0x1070_1777, &node_id(FULL_NODE).to_bytes()));
    net.settle();
    assert_eq!(net.gateway.can_node(newcomer), Some(node_id(FULL_NODE)));
    assert!(!net.gateway_events.iter().any(|e| matches!(e, GatewayEvent::DuplicateNodeId { .. })));
    assert_eq!(sent_since(&net, after), [], "nothing more for the departed node");
    // Forgetting a node twice, or one never seen, is harmless.
    net.gateway.handle_full_node_left(net.now, node_id(FULL_NODE));
    net.gateway.handle_full_node_left(net.now, node_id(STRANGER));
    net.settle();
    assert_eq!(sent_since(&net, after), []);
}

#[test]
fn a_message_held_for_a_node_that_turns_up_on_the_full_side_is_dropped() {
    let mut net = started();
    let stranger = node_id(STRANGER);
    // A message for a node the gateway does not know yet: held while an AME asks CAN for it.
    let verify = Message::addressed(Mti::VERIFY_NODE_ID_ADDRESSED, node_id(FULL_NODE), stranger, &[][..]);
    net.gateway.handle_message(net.now, verify.as_ref());
    net.settle();
    // The node turns out to be on the full-format side (it reached it there), then leaves.
    let hello = Message::global(Mti::INITIALIZATION_COMPLETE, stranger, stranger.to_bytes().to_vec());
    net.gateway.handle_message(net.now, hello.as_ref());
    net.settle();
    net.gateway.handle_full_node_left(net.now, stranger);
    net.settle();
    // Its Node ID logs in on CAN: the old message is not delivered to it.
    let before = net.from_gateway.len();
    net.gateway.handle_can_frame(net.now, &frame(0x1070_1777, &stranger.to_bytes()));
    net.settle();
    assert_eq!(sent_since(&net, before), [], "nothing held for the node went out");
    assert_eq!(net.gateway.stats().stayed_local, 1);
}
