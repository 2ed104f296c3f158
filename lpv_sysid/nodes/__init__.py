"""lpv_sysid.nodes"""
