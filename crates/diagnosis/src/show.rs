//! Show what the simulation gets wrong (issue 6, part 1).
