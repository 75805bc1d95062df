//! How the tool names another node: by its Node ID, or on CAN by its alias while its Node
//! ID is not known (the stack names such a peer by a provisional Node ID made from the
//! alias, which is never printed as if it were a Node ID).

use openlcb_can::NodeAlias;
use openlcb_stream::NodeId;

/// A node as the tool prints it: `05.01.01.01.22.E2`, or `alias 4FF`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(crate) enum Peer {
    /// Known by its Node ID.
    Node(NodeId),
    /// Known only by its CAN alias.
    Alias(NodeAlias),
}

impl Peer {
    /// The peer the stack calls `node`.
    pub(crate) fn of(node: NodeId) -> Peer {
        match NodeAlias::from_provisional(node) {
            Some(alias) => Peer::Alias(alias),
            None => Peer::Node(node),
        }
    }

    /// Its Node ID, for the JSON field that names a node (absent for a peer known by alias).
    pub(crate) fn node_field(self) -> Option<String> {
        match self {
            Peer::Node(node) => Some(node.to_string()),
            Peer::Alias(_) => None,
        }
    }

    /// Its alias in hex (`"4FF"`), for the JSON field beside it (absent for a Node ID).
    pub(crate) fn alias_field(self) -> Option<String> {
        match self {
            Peer::Node(_) => None,
            Peer::Alias(alias) => Some(format!("{:03X}", alias.as_raw())),
        }
    }
}

impl std::fmt::Display for Peer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Peer::Node(node) => write!(f, "{node}"),
            Peer::Alias(alias) => write!(f, "alias {:03X}", alias.as_raw()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_provisional_name_is_shown_as_its_alias_and_a_node_id_as_itself() {
        let provisional = NodeAlias::new(0x4FF).unwrap().provisional_node_id();
        let alias = Peer::of(provisional);
        assert_eq!(
            (alias.to_string(), alias.node_field(), alias.alias_field()),
            ("alias 4FF".into(), None, Some("4FF".into()))
        );
        let node: NodeId = "05.01.01.01.22.E2".parse().unwrap();
        let known = Peer::of(node);
        assert_eq!(
            (known.to_string(), known.node_field(), known.alias_field()),
            ("05.01.01.01.22.E2".into(), Some("05.01.01.01.22.E2".into()), None)
        );
    }
}
