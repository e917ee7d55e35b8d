"""A development corpus of real shapes, rendered by an independent path tracer (Mitsuba 3).

Data flow: ``shapes`` (signed distances and package meshes -> watertight ground-truth meshes with
their genus) and ``envmaps`` (procedural skies with a sun, procedural rooms, the dev scenes' maps)
and ``rigs`` (camera rings) feed ``render`` (Mitsuba scenes, radiance + coverage + AOVs), which
``build`` writes in the layout of ``../shared/data`` (see its README). ``scenes`` lists the
corpus; ``bench`` measures VoxNeRO's presets on it and ``sheet`` draws the contact sheet.

Mitsuba and pybullet are a tools-only extra: ``pip install -e .[scenes]``.
"""
