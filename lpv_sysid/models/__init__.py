"""lpv_sysid.models"""
