"""lpv_sysid.signals"""
