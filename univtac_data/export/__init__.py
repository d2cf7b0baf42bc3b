"""Exports to other ecosystems' formats: LeRobot v3.0 (``export_lerobot``), and the MP4 writer they share."""

from univtac_data.export.lerobot import CODEBASE_VERSION, ExportReport, export_lerobot

__all__ = ["CODEBASE_VERSION", "ExportReport", "export_lerobot"]
