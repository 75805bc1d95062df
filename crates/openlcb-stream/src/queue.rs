//! [`Queue`]: the first-in first-out queue of the stack's outputs.

use alloc::vec::Vec;

/// The first-in first-out queue of the stack's outputs (messages, frames, events).
///
/// A ring of slots in one heap array that doubles when full. It does what the stack needs of
/// `VecDeque` and no more, in less code: on a Cortex-M each element type of `VecDeque` costs
/// about 140 bytes of flash more than this ring (measured on the stream endpoint's queues),
/// and the stack queues a dozen element types. Bounds are the owner's: each queue's owner
/// refuses or counts what would exceed its configured limit before pushing.
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
#[derive(Clone)]
pub struct Queue<T> {
    /// The ring: `len` items from `head`, wrapping; every other slot is `None`.
    slots: Vec<Option<T>>,
    head: usize,
    len: usize,
}

impl<T> Queue<T> {
    /// An empty queue; it allocates on the first push.
    pub const fn new() -> Self {
        Queue { slots: Vec::new(), head: 0, len: 0 }
    }

    /// An empty queue with room for `capacity` items before it first grows.
    pub fn with_capacity(capacity: usize) -> Self {
        let mut queue = Queue::new();
        queue.slots.resize_with(capacity, || None);
        queue
    }

    /// Items in the queue.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the queue is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Items it holds before it grows.
    pub fn capacity(&self) -> usize {
        self.slots.len()
    }

    /// Adds `item` at the back.
    pub fn push_back(&mut self, item: T) {
        self.make_room();
        let index = self.wrap(self.head + self.len);
        self.put(index, item);
    }

    /// Adds `item` at the front.
    pub fn push_front(&mut self, item: T) {
        self.make_room();
        self.head = self.wrap(self.head + self.slots.len() - 1);
        self.put(self.head, item);
    }

    /// Removes the front item.
    pub fn pop_front(&mut self) -> Option<T> {
        if self.len == 0 {
            return None;
        }
        let item = self.slots.get_mut(self.head).and_then(Option::take);
        self.head = self.wrap(self.head + 1);
        self.len -= 1;
        item
    }

    /// The front item.
    pub fn front(&self) -> Option<&T> {
        self.get(0)
    }

    /// The item `index` places behind the front.
    pub fn get(&self, index: usize) -> Option<&T> {
        if index >= self.len {
            return None;
        }
        self.slots.get(self.wrap(self.head + index))?.as_ref()
    }

    /// The item `index` places behind the front, to change in place.
    pub fn get_mut(&mut self, index: usize) -> Option<&mut T> {
        if index >= self.len {
            return None;
        }
        let slot = self.wrap(self.head + index);
        self.slots.get_mut(slot)?.as_mut()
    }

    /// Removes every item.
    pub fn clear(&mut self) {
        while self.pop_front().is_some() {}
        self.head = 0;
    }

    /// Keeps only the items for which `keep` is true, in order.
    pub fn retain(&mut self, mut keep: impl FnMut(&T) -> bool) {
        self.retain_mut(|item| keep(item));
    }

    /// Keeps only the items for which `keep` is true, in order; `keep` may change them.
    pub fn retain_mut(&mut self, mut keep: impl FnMut(&mut T) -> bool) {
        for _ in 0..self.len {
            if let Some(mut item) = self.pop_front() {
                if keep(&mut item) {
                    self.push_back(item);
                }
            }
        }
    }

    /// Removes and returns the item `index` places behind the front.
    pub fn remove(&mut self, index: usize) -> Option<T> {
        let mut removed = None;
        for position in 0..self.len {
            if let Some(item) = self.pop_front() {
                if position == index {
                    removed = Some(item);
                } else {
                    self.push_back(item);
                }
            }
        }
        removed
    }

    /// The items, front first.
    pub fn iter(&self) -> impl Iterator<Item = &T> {
        let (back, front) = self.slots.split_at(self.head);
        front.iter().chain(back).flatten()
    }

    /// The items, front first, to change in place.
    pub fn iter_mut(&mut self) -> impl Iterator<Item = &mut T> {
        let (back, front) = self.slots.split_at_mut(self.head);
        front.iter_mut().chain(back).flatten()
    }

    /// `index` taken round the ring once (`index` < 2 × capacity).
    fn wrap(&self, index: usize) -> usize {
        if index >= self.slots.len() { index - self.slots.len() } else { index }
    }

    fn put(&mut self, index: usize, item: T) {
        if let Some(slot) = self.slots.get_mut(index) {
            *slot = Some(item);
            self.len += 1;
        }
    }

    /// Doubles the ring when it is full: new empty slots at the end, then the items that had
    /// wrapped round to the front move behind the others.
    fn make_room(&mut self) {
        let capacity = self.slots.len();
        if self.len < capacity {
            return;
        }
        self.slots.resize_with((capacity * 2).max(4), || None);
        for index in 0..self.head {
            self.slots.swap(index, capacity + index);
        }
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
        queue.retain(|n| n % 2 == 0);
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
