//! Recycled pixel buffers for frames, so a driver's steady state allocates
//! nothing: a buffer comes back to the pool once every [`crate::Image`]
//! sharing it has been dropped.

use std::sync::Arc;

/// A small pool of `Arc<[u8]>` pixel buffers of one size.
#[derive(Debug, Default)]
pub struct BufferPool {
    len: usize,
    buffers: Vec<Arc<[u8]>>,
    capacity: usize,
}

impl BufferPool {
    /// A pool keeping at most `capacity` buffers (frames held longer than
    /// that by consumers make it allocate fresh ones).
    pub fn new(capacity: usize) -> Self {
        Self {
            len: 0,
            buffers: Vec::new(),
            capacity: capacity.max(1),
        }
    }

    /// A buffer of `len` bytes that no one else holds, filled by `fill`
    /// (which must write every byte it relies on: recycled buffers hold the
    /// previous frame). Changing `len` empties the pool.
    pub fn take(&mut self, len: usize, fill: impl FnOnce(&mut [u8])) -> Arc<[u8]> {
        let mut buffer = self.checkout(len);
        fill(Arc::get_mut(&mut buffer).expect("checkout hands out unique buffers"));
        self.track(&buffer);
        buffer
    }

    /// A buffer of `len` bytes that no one else holds, not yet tracked:
    /// write it through `Arc::get_mut`, then hand it to [`track`](Self::track)
    /// so it comes back when released. Changing `len` empties the pool.
    pub fn checkout(&mut self, len: usize) -> Arc<[u8]> {
        if len != self.len {
            self.buffers.clear();
            self.len = len;
        }
        match self
            .buffers
            .iter_mut()
            .position(|b| Arc::get_mut(b).is_some())
        {
            Some(i) => self.buffers.swap_remove(i),
            None => std::iter::repeat(0u8).take(len).collect(),
        }
    }

    /// Keeps a handle on `buffer` so it is reused once every other holder
    /// has dropped it (ignored when the pool is full or the size differs).
    pub fn track(&mut self, buffer: &Arc<[u8]>) {
        if buffer.len() == self.len && self.buffers.len() < self.capacity {
            self.buffers.push(Arc::clone(buffer));
        }
    }

    /// Buffers the pool owns (in use or free).
    pub fn pooled(&self) -> usize {
        self.buffers.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_are_reused_once_released() {
        let mut pool = BufferPool::new(2);
        let a = pool.take(4, |b| b.fill(1));
        let a_ptr = a.as_ptr();
        let b = pool.take(4, |b| b.fill(2));
        assert_ne!(a.as_ptr(), b.as_ptr());
        assert_eq!((&a[..], &b[..]), (&[1u8; 4][..], &[2u8; 4][..]));
        // Both held: a third is unpooled.
        let c = pool.take(4, |b| b.fill(3));
        assert_eq!(pool.pooled(), 2);
        assert_eq!(&c[..], &[3; 4]);
        drop(a);
        let d = pool.take(4, |b| b.fill(4));
        assert_eq!(d.as_ptr(), a_ptr, "the released buffer comes back");
        assert_eq!(&d[..], &[4; 4]);
        assert_eq!(&b[..], &[2; 4], "a held buffer is never written");
        // A new size starts over.
        let e = pool.take(3, |b| b.fill(5));
        assert_eq!((&e[..], pool.pooled()), (&[5u8; 3][..], 1));
    }
}
