SETS=(--set "objects.train=[cube,frustum]" --set "objects.ood=[]" --set "objects.heldout_pairs=[]"
  --set scenes.singles=false --set scenes.many=false
  --set "scenes.per_combination={train: 10, Pl: 7, Com: 0, Geo: 0, many: 0}"
  --set "synthesis.splits=[train,Pl]" --set "synthesis.max_scenes_per_combination={train: 10, Pl: 7}"
  --set synthesis.optimizer.fc_friction=0.2
  --set specialists.clustering.mode=combination --set specialists.max_bins=1)
X=(--set specialists.ppo.std_mode=independent --set specialists.ppo.reward_scale=0.1
   --set specialists.ppo.critic_warmup_iterations=10 --set specialists.ppo.target_kl=0.02
   --set specialists.ppo.normalizer_frozen_after=10)
