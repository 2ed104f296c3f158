"""lpv_sysid.cli"""
