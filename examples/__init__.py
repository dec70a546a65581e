"""Worked examples of agents from outside nutribench (plug-ins and recorded training loops)."""
