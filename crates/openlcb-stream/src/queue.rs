//! [`Queue`]: the first-in first-out queue of the stack's outputs.

use alloc::vec::Vec;

/// The first-in first-out queue of the stack's outputs (messages, frames, events).
///
/// The items sit in one `Vec`, front first; taking the front moves the rest with one
/// `memmove`. Every queue of the stack is short (drained after each input, or held to a
/// configured limit by its owner, which refuses or counts what would exceed it), and this
/// costs far less flash per element type than a ring: on a Cortex-M the stream endpoint's two
/// queues took 796 bytes less than in a ring, which took less than in `VecDeque`.
///
/// ```
/// use openlcb_stream::Queue;
///
/// let mut queue = Queue::new();
/// queue.push_back(1);
/// queue.push_back(2);
/// queue.push_front(0);
/// queue.retain(|n| *n != 1);
/// assert_eq!(queue.pop_front(), Some(0));
/// assert_eq!(queue.pop_front(), Some(2));
/// assert_eq!(queue.pop_front(), None);
/// ```
pub struct Queue<T> {
    /// The items, front first.
    items: Vec<T>,
}

/// A copy has the same room as the original (a queue filled with
/// [`push_within`](Queue::push_within) never grows, so its copy must not be smaller).
impl<T: Clone> Clone for Queue<T> {
    fn clone(&self) -> Self {
        let mut items = Vec::with_capacity(self.items.capacity());
        items.extend_from_slice(&self.items);
        Queue { items }
    }
}

impl<T> Queue<T> {
    /// An empty queue; it allocates on the first push.
    pub const fn new() -> Self {
        Queue { items: Vec::new() }
    }

    /// An empty queue with room for `capacity` items before it first grows.
    pub fn with_capacity(capacity: usize) -> Self {
        Queue { items: Vec::with_capacity(capacity) }
    }

    /// Items in the queue.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// Whether the queue is empty.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Items it holds before it grows.
    pub fn capacity(&self) -> usize {
        self.items.capacity()
    }

    /// Adds `item` at the back.
    pub fn push_back(&mut self, item: T) {
        self.items.push(item);
    }

    /// Adds `item` at the back if the queue holds fewer than `limit` items and has room for
    /// one more without growing; says whether it did (else `item` is dropped). For a queue
    /// made [`with_capacity`](Self::with_capacity)`(limit)` the room check refuses nothing
    /// more, and lets the compiler leave out the grow path.
    pub fn push_within(&mut self, limit: usize, item: T) -> bool {
        let len = self.items.len();
        let room = len < limit && len < self.items.capacity();
        if room {
            self.items.push(item);
        }
        room
    }

    /// Adds `item` at the front.
    pub fn push_front(&mut self, item: T) {
        self.items.insert(0, item);
    }

    /// Removes the front item.
    pub fn pop_front(&mut self) -> Option<T> {
        self.remove(0)
    }

    /// The front item.
    pub fn front(&self) -> Option<&T> {
        self.items.first()
    }

    /// The item `index` places behind the front.
    pub fn get(&self, index: usize) -> Option<&T> {
        self.items.get(index)
    }

    /// The item `index` places behind the front, to change in place.
    pub fn get_mut(&mut self, index: usize) -> Option<&mut T> {
        self.items.get_mut(index)
    }

    /// Removes every item.
    pub fn clear(&mut self) {
        self.items.clear();
    }

    /// Keeps only the items for which `keep` is true, in order; returns how many it removed.
    pub fn retain(&mut self, mut keep: impl FnMut(&T) -> bool) -> usize {
        self.retain_mut(|item| keep(item))
    }

    /// Keeps only the items for which `keep` is true, in order; `keep` may change them.
    /// Returns how many it removed.
    pub fn retain_mut(&mut self, mut keep: impl FnMut(&mut T) -> bool) -> usize {
        // One `remove` per item dropped rather than `Vec::retain_mut`: less code per element
        // type, and the queues are short.
        let (mut index, mut removed) = (0, 0);
        while let Some(item) = self.items.get_mut(index) {
            if keep(item) {
                index += 1;
            } else {
                self.items.remove(index);
                removed += 1;
            }
        }
        removed
    }

    /// Removes and returns the item `index` places behind the front.
    pub fn remove(&mut self, index: usize) -> Option<T> {
        (index < self.items.len()).then(|| self.items.remove(index))
    }

    /// The items, front first.
    pub fn iter(&self) -> core::slice::Iter<'_, T> {
        self.items.iter()
    }

    /// The items, front first, to change in place.
    pub fn iter_mut(&mut self) -> core::slice::IterMut<'_, T> {
        self.items.iter_mut()
    }
}

impl<T> Default for Queue<T> {
    fn default() -> Self {
        Queue::new()
    }
}

impl<T: core::fmt::Debug> core::fmt::Debug for Queue<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

#[cfg(test)]
mod tests {
    use alloc::vec::Vec;

    use super::Queue;

    fn items(queue: &Queue<u32>) -> Vec<u32> {
        queue.iter().copied().collect()
    }

    #[test]
    fn push_within_stops_at_the_limit_and_a_copy_keeps_the_room() {
        let mut queue = Queue::with_capacity(3);
        assert!(queue.push_within(2, 1));
        assert!(queue.push_within(2, 2));
        assert!(!queue.push_within(2, 3), "at the limit");
        let mut copy = queue.clone();
        assert!(copy.push_within(3, 3), "the copy has the original's room");
        assert!(!copy.push_within(4, 4), "no room left: never grows");
        assert_eq!(items(&copy), [1, 2, 3]);
        assert_eq!(items(&queue), [1, 2]);
        assert!(!Queue::new().push_within(1, 0), "no room allocated");
    }

    #[test]
    fn keeps_order_across_wrap_and_growth() {
        let mut queue = Queue::with_capacity(4);
        let mut model = alloc::collections::VecDeque::new();
        for round in 0..200u32 {
            // Push three, pop two: the ring wraps and grows while items are in it.
            for n in 0..3 {
                queue.push_back(round * 3 + n);
                model.push_back(round * 3 + n);
            }
            if round % 7 == 0 {
                queue.push_front(round);
                model.push_front(round);
            }
            assert_eq!(queue.pop_front(), model.pop_front());
            assert_eq!(queue.pop_front(), model.pop_front());
            assert_eq!(queue.len(), model.len());
            assert_eq!(queue.front(), model.front());
            assert_eq!(queue.get(5), model.get(5));
            assert_eq!(items(&queue), model.iter().copied().collect::<Vec<_>>());
        }
        assert!(queue.capacity() >= queue.len());
        assert!(queue.capacity() < 2 * model.len() + 8, "grows by doubling only when full");
    }

    #[test]
    fn retain_remove_and_iter_mut_change_the_right_items() {
        let mut queue = Queue::new();
        for n in 0..10u32 {
            queue.push_back(n);
        }
        for _ in 0..3 {
            let front = queue.pop_front();
            queue.push_back(front.unwrap_or(99) + 100);
        }
        assert_eq!(items(&queue), [3, 4, 5, 6, 7, 8, 9, 100, 101, 102]);
        assert_eq!(queue.retain(|n| n % 2 == 0), 5);
        assert_eq!(items(&queue), [4, 6, 8, 100, 102]);
        assert_eq!(queue.remove(1), Some(6));
        if let Some(n) = queue.get_mut(1) {
            *n += 10;
        }
        assert_eq!(queue.get_mut(4), None);
        assert_eq!(items(&queue), [4, 18, 100, 102]);
        queue.retain(|n| *n != 18);
        queue.push_back(8);
        queue.retain(|n| *n != 100);
        queue.push_front(6);
        queue.retain(|n| *n != 6);
        queue.push_front(8);
        assert_eq!(queue.remove(0), Some(8));
        assert_eq!(queue.remove(9), None);
        for n in queue.iter_mut() {
            *n += 1;
        }
        assert_eq!(items(&queue), [5, 103, 9]);
        queue.clear();
        assert!(queue.is_empty());
        assert_eq!(queue.pop_front(), None);
        queue.push_front(7);
        assert_eq!(items(&queue), [7]);
    }
}
