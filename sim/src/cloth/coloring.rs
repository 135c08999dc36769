//! Greedy graph colouring of constraints: constraints of one colour share no particle, so
//! a colour can be solved in any order, or in parallel, with the same result.

/// Assigns each constraint (given by the particles it touches) the smallest colour none of
/// its particles already has. Returns the colour of each constraint and the colour count.
pub fn greedy(constraints: &[&[u32]], particles: usize) -> (Vec<u32>, u32) {
    let mut used: Vec<Vec<u32>> = vec![Vec::new(); particles];
    let mut colours = Vec::with_capacity(constraints.len());
    let mut count = 0;
    for c in constraints {
        let mut colour = 0u32;
        while c.iter().any(|&p| used[p as usize].contains(&colour)) {
            colour += 1;
        }
        for &p in c.iter() {
            used[p as usize].push(colour);
        }
        count = count.max(colour + 1);
        colours.push(colour);
    }
    (colours, count)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_colour_shares_a_particle() {
        // A fan of 20 edges around particle 0 plus a ring: 20+ colours are needed at 0.
        let mut edges: Vec<[u32; 2]> = (1..=20).map(|i| [0, i]).collect();
        edges.extend((1..20).map(|i| [i, i + 1]));
        let refs: Vec<&[u32]> = edges.iter().map(|e| &e[..]).collect();
        let (colours, count) = greedy(&refs, 21);
        assert!((20..=22).contains(&count));
        for a in 0..edges.len() {
            for b in a + 1..edges.len() {
                if colours[a] == colours[b] {
                    assert!(edges[a].iter().all(|p| !edges[b].contains(p)));
                }
            }
        }
    }
}
