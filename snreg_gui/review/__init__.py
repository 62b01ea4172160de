"""The Review tab: a saved session read-only, its timelines, nodes with snapshots and stored registrations."""
