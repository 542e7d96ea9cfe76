"""Assembly cycles and campaigns: legs as ordinary plan calls plus events, in a cabin that fills up."""
