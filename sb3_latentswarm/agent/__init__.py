"""Decentralized execution: one UAV's policy step, its ONNX export, and a torch-free runtime for the exported file.

The names load on first use (PEP 562): ``OnnxSwarmAgent`` runs with numpy and onnxruntime only, without torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sb3_latentswarm._lazy import lazy_exports

_EXPORTS = {  # the module that defines them -> public names
    "sb3_latentswarm.agent.agent": ("LatentSwarmAgent",),
    "sb3_latentswarm.agent.inputs": ("AgentStepInfo",),
    "sb3_latentswarm.agent.export": ("ExportCheck", "export_onnx"),
    "sb3_latentswarm.agent.onnx_runtime": ("OnnxSwarmAgent",),
}

if TYPE_CHECKING:
    from sb3_latentswarm.agent.agent import LatentSwarmAgent
    from sb3_latentswarm.agent.export import ExportCheck, export_onnx
    from sb3_latentswarm.agent.inputs import AgentStepInfo
    from sb3_latentswarm.agent.onnx_runtime import OnnxSwarmAgent


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["AgentStepInfo", "ExportCheck", "LatentSwarmAgent", "OnnxSwarmAgent", "export_onnx"]
