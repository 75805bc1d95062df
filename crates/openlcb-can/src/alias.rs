//! [`NodeAlias`], the 12-bit CAN stand-in for a Node ID, and the Technical Note's preferred
//! [`AliasGenerator`].

use core::fmt;
use core::num::NonZeroU16;

use openlcb_stream::NodeId;

/// A 12-bit CAN node alias (CFT §6.3): 0x001..=0xFFF. Zero is never an alias, which makes
/// `Option<NodeAlias>` as small and cheap as the alias itself.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct NodeAlias(NonZeroU16);

impl NodeAlias {
    /// The largest alias, 0xFFF.
    pub const MAX: NodeAlias = NodeAlias(NonZeroU16::MIN.saturating_add(0xFFE));

    /// An alias, or `None` for 0 or a value above 12 bits.
    pub const fn new(raw: u16) -> Option<Self> {
        match NonZeroU16::new(raw) {
            Some(raw) if raw.get() <= 0xFFF => Some(NodeAlias(raw)),
            _ => None,
        }
    }

    /// The alias in the low 12 bits of `bits` (higher bits are dropped), or `None` if those
    /// 12 bits are zero. For reading header and data fields.
    pub const fn from_low_bits(bits: u32) -> Option<Self> {
        Self::new((bits & 0xFFF) as u16)
    }

    /// The raw 12-bit value.
    pub const fn as_raw(self) -> u16 {
        self.0.get()
    }

    /// The provisional name of a peer known only by this alias: the alias in the low 12 bits,
    /// every other bit 0 (`00.00.00.00.0A.AA`). A Node ID whose first byte is 0x00 is reserved
    /// and never belongs to a real node (UID §5.13), so the name cannot clash with one.
    /// [`CanLink`](crate::CanLink) delivers messages from an alias whose Node ID it does not
    /// know under this name, and sends messages addressed to it straight to the alias.
    pub const fn provisional_node_id(self) -> NodeId {
        let [high, low] = self.as_raw().to_be_bytes();
        NodeId::from_bytes([0, 0, 0, 0, high, low])
    }

    /// The alias named by a provisional Node ID ([`provisional_node_id`](Self::provisional_node_id)),
    /// or `None` if `node` is not one: bits 47-12 must be 0 and bits 11-0 a valid alias.
    pub const fn from_provisional(node: NodeId) -> Option<NodeAlias> {
        let raw = node.as_raw();
        if raw >> 12 != 0 { None } else { Self::new(raw as u16) }
    }
}

impl fmt::Debug for NodeAlias {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "NodeAlias(0x{:03X})", self.as_raw())
    }
}

impl fmt::Display for NodeAlias {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:03X}", self.as_raw())
    }
}

/// The preferred alias generator of the CAN Frame Transfer Technical Note (§6; wire-spec
/// §7.5): a 48-bit state seeded with the Node ID, stepped as
/// `x <- (2^9 + 1) * x + 0x1B0CA37A4BA9 (mod 2^48)`; the alias is the XOR of the state's four
/// 12-bit pieces. The current state gives the next alias; a state whose alias is zero is
/// skipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AliasGenerator {
    state: u64,
}

impl AliasGenerator {
    const MASK: u64 = 0xFFFF_FFFF_FFFF;
    const INCREMENT: u64 = 0x1B0C_A37A_4BA9;

    /// A generator seeded with `node`, as the Technical Note prefers.
    pub const fn new(node: NodeId) -> Self {
        AliasGenerator { state: node.as_raw() }
    }

    /// A generator seeded with any 48-bit value (higher bits are dropped).
    pub const fn from_seed(seed: u64) -> Self {
        AliasGenerator { state: seed & Self::MASK }
    }

    /// The 48-bit state.
    pub const fn state(&self) -> u64 {
        self.state
    }

    /// The alias value of the current state, possibly zero.
    pub const fn current_raw(&self) -> u16 {
        let high = self.state >> 24;
        let low = self.state & 0xFF_FFFF;
        ((high ^ low ^ (high >> 12) ^ (low >> 12)) & 0xFFF) as u16
    }

    /// Moves to the next state.
    pub const fn step(&mut self) {
        self.state = (self.state.wrapping_mul((1 << 9) + 1).wrapping_add(Self::INCREMENT)) & Self::MASK;
    }

    /// The alias of the current state, skipping states whose alias is zero, then steps past it.
    pub fn next_alias(&mut self) -> NodeAlias {
        loop {
            let candidate = NodeAlias::new(self.current_raw());
            self.step();
            if let Some(alias) = candidate {
                return alias;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alias_range() {
        assert_eq!(NodeAlias::new(0), None);
        assert_eq!(NodeAlias::new(0x1000), None);
        assert_eq!(NodeAlias::new(0xFFF), Some(NodeAlias::MAX));
        assert_eq!(NodeAlias::from_low_bits(0x1F45_6123).map(NodeAlias::as_raw), Some(0x123));
        assert_eq!(NodeAlias::from_low_bits(0x1000), None);
        assert_eq!(format!("{:?} {}", NodeAlias::MAX, NodeAlias::MAX), "NodeAlias(0xFFF) 0xFFF");
        assert_eq!(size_of::<Option<NodeAlias>>(), 2, "zero is the niche of `None`");
    }

    #[test]
    fn provisional_names_round_trip() {
        let name = alias(0x031).provisional_node_id();
        assert_eq!(name.as_raw(), 0x0000_0000_0031);
        assert_eq!(name.to_string(), "00.00.00.00.00.31");
        assert_eq!(NodeAlias::from_provisional(name), Some(alias(0x031)));
        assert_eq!(NodeAlias::MAX.provisional_node_id().as_raw(), 0xFFF);
        assert_eq!(NodeAlias::from_provisional(NodeAlias::MAX.provisional_node_id()), Some(NodeAlias::MAX));
        // Not provisional: a bit above 11 set, or alias 0.
        for raw in [0x0000_0000_1031, 0x0501_0101_2200, 0x8000_0000_0031, 0] {
            assert_eq!(NodeAlias::from_provisional(NodeId::new(raw).unwrap()), None, "{raw:012X}");
        }
    }

    fn alias(raw: u16) -> NodeAlias {
        NodeAlias::new(raw).unwrap()
    }

    /// The check table of the CAN Frame Transfer TN appendix (wire-spec §7.5).
    #[test]
    fn generator_matches_technical_note_table() {
        let mut g = AliasGenerator::from_seed(0);
        assert_eq!(g.current_raw(), 0x000);
        g.step();
        assert_eq!(g.state(), 0x1B0C_A37A_4BA9);
        assert_eq!(g.current_raw(), 0x11E);
        g.step();
        assert_eq!(g.state(), 0x4F60_3B8B_E952);
        assert_eq!(g.current_raw(), 0x521);

        let mut g = AliasGenerator::new(NodeId::new(0x0201_2100_0012).unwrap());
        assert_eq!(g.current_raw(), 0x113);
        g.step();
        assert_eq!(g.state(), 0x1F4F_C47A_6FBB);
        assert_eq!(g.current_raw(), 0x62D);
    }

    #[test]
    fn next_alias_skips_zero() {
        let mut g = AliasGenerator::from_seed(0);
        assert_eq!(g.next_alias().as_raw(), 0x11E);
        assert_eq!(g.next_alias().as_raw(), 0x521);
    }

    #[test]
    fn worked_example_nodes_get_the_documented_aliases() {
        // wire-spec §9.2: the preferred generator would pick 0x343 for A and 0x342 for B.
        let a = AliasGenerator::new(NodeId::new(0x0501_0101_2200).unwrap());
        let b = AliasGenerator::new(NodeId::new(0x0501_0101_2201).unwrap());
        assert_eq!((a.current_raw(), b.current_raw()), (0x343, 0x342));
    }
}
