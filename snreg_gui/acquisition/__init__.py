"""The Acquisition tab: live feeds with the probe overlay, stream health, Store SN and undo, and its worker."""
