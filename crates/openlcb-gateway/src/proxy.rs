//! A full-format node the gateway holds a CAN alias for.

use openlcb_can::{AliasLogin, LoginState, NodeAlias};
use openlcb_stream::{Duration, Instant, NodeId};

/// One proxied node: its alias login (CID, RID, AMD, defence, AME answers) and when it last
/// had traffic, for eviction.
#[derive(Debug)]
pub(crate) struct Proxy {
    pub(crate) node: NodeId,
    pub(crate) login: AliasLogin,
    pub(crate) last_used: Instant,
    /// The alias last announced (AMD) for the node: messages queued with it must be dropped
    /// if the login stops.
    pub(crate) announced: Option<NodeAlias>,
    /// The node left the full-format link at this time: what it sent still goes out, then
    /// its alias is released.
    pub(crate) left_at: Option<Instant>,
}

impl Proxy {
    /// Starts the login of `node` at `now`; its CID frames are queued in the login.
    pub(crate) fn new(now: Instant, node: NodeId, reserve_wait: Duration) -> Self {
        Proxy {
            node,
            login: AliasLogin::new(now, node, None, reserve_wait),
            last_used: now,
            announced: None,
            left_at: None,
        }
    }

    /// The alias messages from this node may be sent with.
    pub(crate) fn permitted_alias(&self) -> Option<NodeAlias> {
        self.login.alias()
    }

    /// The alias held or being checked.
    pub(crate) fn any_alias(&self) -> Option<NodeAlias> {
        match self.login.state() {
            LoginState::Checking { alias, .. } | LoginState::Permitted { alias } => Some(alias),
            _ => None,
        }
    }

    /// The tentative alias, while checking.
    pub(crate) fn checking_alias(&self) -> Option<NodeAlias> {
        match self.login.state() {
            LoginState::Checking { alias, .. } => Some(alias),
            _ => None,
        }
    }

    /// A duplicate Node ID stopped the login: nothing is sent for this node any more.
    pub(crate) fn is_stopped(&self) -> bool {
        self.login.state() == LoginState::Stopped
    }
}
