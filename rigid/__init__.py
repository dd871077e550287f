"""Rigid bodies: mass properties, state, integration, contacts, shape matching."""
