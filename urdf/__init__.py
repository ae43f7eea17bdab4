"""Embedded robot files (URDF open trees + closure sidecars), shipped as package data."""
