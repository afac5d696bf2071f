"""Wire-level emulators: processes that speak the real protocols with virtual physics."""
