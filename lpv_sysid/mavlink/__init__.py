"""lpv_sysid.mavlink"""
