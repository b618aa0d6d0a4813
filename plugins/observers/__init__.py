"""Observers: follow a run through the event hooks (e.g. record it), one observer per entry."""
