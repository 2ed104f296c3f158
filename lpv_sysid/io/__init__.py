"""lpv_sysid.io"""
