//! [`Fifo`]: the link's and the login's bounded first-in first-out queues.

use alloc::vec::Vec;

/// A first-in first-out queue in one `Vec`, front first. Its owner bounds it (each queue has
/// a configured limit, taken up front), so the queues are short and taking the front moves
/// the rest with one `memmove`: far less flash per element type than a ring.
#[derive(Debug, Clone)]
pub(crate) struct Fifo<T>(Vec<T>);

impl<T> Fifo<T> {
    /// An empty queue with room for `capacity` items before it first grows.
    pub(crate) fn with_capacity(capacity: usize) -> Self {
        Fifo(Vec::with_capacity(capacity))
    }

    /// Adds `item` at the back.
    pub(crate) fn push_back(&mut self, item: T) {
        self.0.push(item);
    }

    /// Adds `item` at the front.
    pub(crate) fn push_front(&mut self, item: T) {
        self.0.insert(0, item);
    }

    /// Removes the front item.
    pub(crate) fn pop_front(&mut self) -> Option<T> {
        self.remove(0)
    }

    /// Removes the item `index` places behind the front.
    pub(crate) fn remove(&mut self, index: usize) -> Option<T> {
        if index < self.0.len() { Some(self.0.remove(index)) } else { None }
    }

    /// Keeps only the items for which `keep` is true, in order; returns how many it removed.
    pub(crate) fn retain(&mut self, mut keep: impl FnMut(&T) -> bool) -> usize {
        let mut removed = 0;
        let mut index = 0;
        while let Some(item) = self.0.get(index) {
            if keep(item) {
                index += 1;
            } else {
                self.0.remove(index);
                removed += 1;
            }
        }
        removed
    }

    /// Removes every item.
    pub(crate) fn clear(&mut self) {
        self.0.clear();
    }

    /// The items, front first, to change in place.
    pub(crate) fn iter_mut(&mut self) -> core::slice::IterMut<'_, T> {
        self.0.iter_mut()
    }
}

impl<T> core::ops::Deref for Fifo<T> {
    type Target = [T];

    fn deref(&self) -> &[T] {
        &self.0
    }
}
