//! The set bits of a child or lane mask, lowest first: the loops over the
//! lanes of a packet or lane group that ended or push ([`super::packet`],
//! [`super::cast_lanes`]) and over a node's children ([`super::beam`]).

/// The indices of the set bits of `m`, lowest first.
#[inline(always)]
pub fn set_bits(mut m: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (m != 0).then(|| {
            let l = m.trailing_zeros() as usize;
            m &= m - 1;
            l
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_bits_are_listed_lowest_first() {
        assert_eq!(set_bits(0).count(), 0);
        assert_eq!(set_bits(0b1010_0001).collect::<Vec<_>>(), [0, 5, 7]);
        assert_eq!(set_bits(1 << 31).collect::<Vec<_>>(), [31]);
        assert_eq!(set_bits(u32::MAX).count(), 32);
    }
}
