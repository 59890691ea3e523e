//! blueshift-spectrum (being written).
