//! [`AliasCache`]: the bounded alias <-> Node ID table of remote nodes, least recently used
//! entry evicted first.

use alloc::vec::Vec;

use openlcb_stream::NodeId;

use crate::NodeAlias;

#[derive(Debug, Clone, Copy)]
#[repr(C)] // Fields in the order written: short Thumb loads reach the ones read first.
struct Entry {
    alias: NodeAlias,
    node: NodeId,
}

/// Alias mappings of remote nodes, at most `capacity` of them. Each alias and each Node ID
/// appears at most once. Lookups that find an entry mark it used.
#[derive(Debug)]
pub struct AliasCache {
    /// Least recently used first: marking an entry used moves it to the back.
    entries: Vec<Entry>,
    capacity: usize,
}

/// A copy keeps the room for `capacity` entries (a derived clone would allocate only the
/// entries held, and the cache never grows).
impl Clone for AliasCache {
    fn clone(&self) -> Self {
        let mut entries = Vec::with_capacity(self.capacity);
        entries.extend_from_slice(&self.entries);
        AliasCache { entries, capacity: self.capacity }
    }
}

impl AliasCache {
    /// An empty cache holding at most `capacity` mappings (all memory taken up front).
    pub fn new(capacity: usize) -> Self {
        AliasCache { entries: Vec::with_capacity(capacity), capacity }
    }

    /// Records `alias` <-> `node`, replacing any mapping of either. Returns the mapping
    /// evicted to make room, if one was.
    pub fn insert(&mut self, alias: NodeAlias, node: NodeId) -> Option<(NodeAlias, NodeId)> {
        let mut index = 0;
        while let Some(e) = self.entries.get(index) {
            if e.alias == alias || e.node == node {
                self.take(index);
            } else {
                index += 1;
            }
        }
        if self.capacity == 0 {
            return None;
        }
        let evicted = if self.entries.len() >= self.capacity { self.take(0) } else { None };
        self.push(Entry { alias, node });
        evicted.map(|e| (e.alias, e.node))
    }

    /// The node holding `alias`, marking the entry used.
    pub fn node(&mut self, alias: NodeAlias) -> Option<NodeId> {
        let index = self.entries.iter().position(|e| e.alias == alias)?;
        self.touch(index);
        self.entries.last().map(|e| e.node)
    }

    /// The alias of `node`, marking the entry used.
    pub fn alias(&mut self, node: NodeId) -> Option<NodeAlias> {
        let index = self.entries.iter().position(|e| e.node == node)?;
        self.touch(index);
        self.entries.last().map(|e| e.alias)
    }

    /// The node holding `alias`, without marking it used.
    pub fn peek_node(&self, alias: NodeAlias) -> Option<NodeId> {
        self.entries.iter().find(|e| e.alias == alias).map(|e| e.node)
    }

    /// The alias of `node`, without marking it used.
    pub fn peek_alias(&self, node: NodeId) -> Option<NodeAlias> {
        self.entries.iter().find(|e| e.node == node).map(|e| e.alias)
    }

    /// Forgets `alias` and returns the node that held it.
    pub fn remove_alias(&mut self, alias: NodeAlias) -> Option<NodeId> {
        let index = self.entries.iter().position(|e| e.alias == alias)?;
        self.take(index).map(|e| e.node)
    }

    /// Forgets the most recently used mapping and returns it.
    pub(crate) fn pop(&mut self) -> Option<(NodeAlias, NodeId)> {
        self.entries.pop().map(|e| (e.alias, e.node))
    }

    /// Forgets every mapping (a global AME, CFT §6.2.3).
    pub fn clear(&mut self) {
        self.entries.clear();
    }

    /// Every mapping held, least recently used first, without marking any used.
    pub fn iter(&self) -> impl Iterator<Item = (NodeAlias, NodeId)> + '_ {
        self.entries.iter().map(|e| (e.alias, e.node))
    }

    /// Removes the entry at `index`, keeping the order of the others.
    fn take(&mut self, index: usize) -> Option<Entry> {
        (index < self.entries.len()).then(|| self.entries.remove(index))
    }

    /// Adds `entry` at the back, within the allocation made by [`new`](Self::new) (callers
    /// make room first): the cache never grows, and this takes no grow path.
    fn push(&mut self, entry: Entry) {
        if self.entries.len() < self.entries.capacity() {
            self.entries.push(entry);
        }
    }

    /// Marks the entry at `index` used: it moves to the back (where it usually is already).
    fn touch(&mut self, index: usize) {
        if index + 1 < self.entries.len()
            && let Some(entry) = self.take(index)
        {
            self.push(entry);
        }
    }

    /// The most mappings held at once.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Mappings held.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// No mapping is held.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alias(raw: u16) -> NodeAlias {
        NodeAlias::new(raw).unwrap()
    }

    fn node(raw: u64) -> NodeId {
        NodeId::new(raw).unwrap()
    }

    #[test]
    fn a_copy_has_room_for_capacity_entries() {
        let mut cache = AliasCache::new(3);
        cache.insert(alias(0x456), node(2));
        let mut copy = cache.clone();
        copy.insert(alias(0x457), node(3));
        copy.insert(alias(0x458), node(4));
        assert_eq!(copy.len(), 3);
        assert_eq!(copy.peek_node(alias(0x458)), Some(node(4)));
        assert_eq!(cache.len(), 1);
    }

    #[test]
    fn maps_both_ways_and_replaces_stale_entries() {
        let mut cache = AliasCache::new(4);
        cache.insert(alias(0x456), node(2));
        assert_eq!(cache.node(alias(0x456)), Some(node(2)));
        assert_eq!(cache.alias(node(2)), Some(alias(0x456)));
        // The node came back with a new alias: the old one is gone.
        cache.insert(alias(0x789), node(2));
        assert_eq!(cache.peek_node(alias(0x456)), None);
        assert_eq!(cache.peek_alias(node(2)), Some(alias(0x789)));
        // Another node took the alias: the old node is gone.
        cache.insert(alias(0x789), node(3));
        assert_eq!(cache.peek_alias(node(2)), None);
        assert_eq!(cache.len(), 1);
    }

    #[test]
    fn evicts_the_least_recently_used() {
        let mut cache = AliasCache::new(2);
        cache.insert(alias(1), node(1));
        cache.insert(alias(2), node(2));
        cache.node(alias(1));
        assert_eq!(cache.insert(alias(3), node(3)), Some((alias(2), node(2))));
        assert_eq!(cache.peek_node(alias(1)), Some(node(1)));
        assert_eq!(cache.len(), 2);
    }

    #[test]
    fn remove_and_clear() {
        let mut cache = AliasCache::new(2);
        cache.insert(alias(1), node(1));
        assert_eq!(cache.remove_alias(alias(1)), Some(node(1)));
        assert_eq!(cache.remove_alias(alias(1)), None);
        cache.insert(alias(2), node(2));
        cache.insert(alias(3), node(3));
        let mut all: Vec<_> = cache.iter().collect();
        all.sort();
        assert_eq!(all, [(alias(2), node(2)), (alias(3), node(3))]);
        assert_eq!(cache.capacity(), 2);
        cache.clear();
        assert!(cache.is_empty());
    }

    #[test]
    fn zero_capacity_holds_nothing() {
        let mut cache = AliasCache::new(0);
        assert_eq!(cache.insert(alias(1), node(1)), None);
        assert!(cache.is_empty());
    }
}
