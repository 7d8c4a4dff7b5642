"""Stage 1: IFC parsing. The only subpackage that imports ifcopenshell."""
