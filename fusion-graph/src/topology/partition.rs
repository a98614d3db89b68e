//! Parts of the fusion graph for the machine's cores: which core each
//! node's processes run on when a network has many more nodes than cores.
//!
//! A consensus round wakes each node once per neighbour's value. A wake-up
//! of a process that last ran on the other core costs an inter-processor
//! interrupt and, on a virtual machine, often the host's wake-up of an idle
//! virtual CPU: `perf bench sched pipe` takes 40.7 µs a round trip across
//! the two cores of the machine the performance figures come from, and
//! 5.2 µs with both ends on one. Nodes placed so that most neighbours
//! share a core keep most wake-ups on it.
//!
//! The parts come from recursive coordinate bisection: the fusion graph
//! links nodes by distance, so a cut across the field's longer side
//! crosses few of its links. Parts differ in size by at most one node.

use super::Topology;

impl Topology {
    /// The part (0..parts) of each node: `parts` sets of nearly equal
    /// size, each a compact region of the field. Every process that
    /// computes it from the same topology gets the same answer.
    pub fn core_parts(&self, parts: usize) -> Vec<usize> {
        let mut part = vec![0; self.nodes()];
        let nodes: Vec<u16> = (0..self.nodes() as u16).collect();
        self.bisect(nodes, 0, parts.max(1), &mut part);
        part
    }

    /// Splits `nodes` into `parts` parts numbered from `first`: across the
    /// longer side of their bounding box, in proportion to the parts on
    /// each side, and again within each side.
    fn bisect(&self, mut nodes: Vec<u16>, first: usize, parts: usize, part: &mut [usize]) {
        if parts <= 1 || nodes.len() <= 1 {
            for n in nodes {
                part[n as usize] = first;
            }
            return;
        }
        let axis = usize::from(self.extent(&nodes, 1) > self.extent(&nodes, 0));
        // By the axis, then the other, then the index: a total order, so
        // that ties (a grid's columns) split the same way everywhere.
        nodes.sort_by(|&a, &b| {
            let (p, q) = (
                self.node_positions[a as usize],
                self.node_positions[b as usize],
            );
            p[axis]
                .total_cmp(&q[axis])
                .then(p[1 - axis].total_cmp(&q[1 - axis]))
                .then(a.cmp(&b))
        });
        let low_parts = parts / 2;
        let low_len = nodes.len() * low_parts / parts;
        let high = nodes.split_off(low_len);
        self.bisect(nodes, first, low_parts, part);
        self.bisect(high, first + low_parts, parts - low_parts, part);
    }

    fn extent(&self, nodes: &[u16], axis: usize) -> f64 {
        let values = nodes.iter().map(|&n| self.node_positions[n as usize][axis]);
        let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
        hi - lo
    }
}

#[cfg(test)]
mod tests {
    use crate::topology::Topology;

    fn grid(rows: u32, cols: u32, width: f64, height: f64) -> Topology {
        crate::topology::test_grid(cols, rows, width, height)
    }

    fn sizes(parts: &[usize], k: usize) -> Vec<usize> {
        (0..k)
            .map(|p| parts.iter().filter(|&&x| x == p).count())
            .collect()
    }

    /// Links of the fusion graph whose ends are in different parts.
    fn cut(t: &Topology, parts: &[usize]) -> usize {
        (0..t.nodes())
            .flat_map(|n| t.neighbours[n].iter().map(move |&m| (n, m as usize)))
            .filter(|&(n, m)| n < m && parts[n] != parts[m])
            .count()
    }

    #[test]
    fn a_square_grid_halves_along_a_line_of_nodes() {
        let t = grid(10, 10, 5000.0, 5000.0);
        let parts = t.core_parts(2);
        assert_eq!(sizes(&parts, 2), vec![50, 50]);
        // Each half is five whole columns (or rows): one of the field's
        // two coordinates separates them.
        let separated = (0..2).any(|axis| {
            let side = |p| {
                (0..t.nodes())
                    .filter(|&n| parts[n] == p)
                    .map(|n| t.node_positions[n][axis])
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                        (lo.min(v), hi.max(v))
                    })
            };
            let (a, b) = (side(0), side(1));
            a.1 < b.0 || b.1 < a.0
        });
        assert!(separated, "the halves overlap: {parts:?}");
        // The cut of two halves of the grid is a small share of its links.
        let links: usize = (0..t.nodes()).map(|n| t.neighbours[n].len()).sum::<usize>() / 2;
        let crossing = cut(&t, &parts);
        assert!(crossing * 8 < links, "{crossing} of {links} links cross");
    }

    #[test]
    fn parts_differ_by_at_most_one_node() {
        let t = grid(7, 9, 4000.0, 3000.0);
        for k in [1, 2, 3, 4, 5, 8, 63, 64, 100] {
            let s = sizes(&t.core_parts(k), k);
            let (lo, hi) = (s.iter().min().unwrap(), s.iter().max().unwrap());
            assert!(hi - lo <= 1, "{k} parts: {s:?}");
            assert_eq!(s.iter().sum::<usize>(), 63);
        }
    }

    #[test]
    fn a_long_field_is_cut_across_its_length() {
        // 2 rows of 12 over a field six times as long as it is high: the
        // halves are the left and right six columns, with a cut of about
        // 2 rows' links, not the top and bottom rows (12 columns' links).
        let t = grid(2, 12, 6000.0, 1000.0);
        let parts = t.core_parts(2);
        let left = |n: usize| t.node_positions[n][0] < 3000.0;
        let first = parts[0];
        for (n, &p) in parts.iter().enumerate() {
            assert_eq!(p == first, left(n) == left(0), "node {n}");
        }
    }
}
