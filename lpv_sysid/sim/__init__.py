"""lpv_sysid.sim"""
