"""Forced and damped responses (issue 34): damping, the averaged reduced dynamics of one master, its FRCs."""
