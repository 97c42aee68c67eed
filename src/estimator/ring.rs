//! Fixed-capacity ring buffer; pushing never allocates.

#[derive(Debug, Clone)]
pub struct Ring<T: Copy> {
    buf: Vec<T>,
    cap: usize,
    head: usize,
}

impl<T: Copy> Ring<T> {
    pub fn with_capacity(cap: usize) -> Self {
        let cap = cap.max(1);
        Self {
            buf: Vec::with_capacity(cap),
            cap,
            head: 0,
        }
    }
    pub fn len(&self) -> usize {
        self.buf.len()
    }
    /// Append, overwriting the oldest element when full.
    pub fn push(&mut self, x: T) {
        if self.buf.len() < self.cap {
            self.buf.push(x);
        } else {
            self.buf[self.head] = x;
            self.head = (self.head + 1) % self.cap;
        }
    }
    /// Element `i`, 0 = oldest.
    pub fn get(&self, i: usize) -> T {
        debug_assert!(i < self.buf.len());
        if self.buf.len() < self.cap {
            self.buf[i]
        } else {
            self.buf[(self.head + i) % self.cap]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Ring;
    #[test]
    fn wraps_keeping_order() {
        let mut r = Ring::with_capacity(3);
        for i in 0..5 {
            r.push(i);
        }
        assert_eq!((r.get(0), r.get(1), r.get(2)), (2, 3, 4));
    }
}
