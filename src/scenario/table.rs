//! Monte Carlo tables: every method over many seeds (filled in below).
