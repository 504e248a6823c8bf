"""Coordination in time: timed routes, the space-time plan, the occlusion certificate, the schedule
clocks and the in-flight re-plans that keep the sight lines blocked (docs/design.md, "Coordinated timing")."""
