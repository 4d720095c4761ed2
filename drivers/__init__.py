"""Instrument drivers. Each driver gets a transport and never knows what is on the other end."""
