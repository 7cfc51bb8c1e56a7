%% @doc Internal. Why an entry is unbound, for the bindings route
%% (evatar_ops:bindings/1) and the dashboard's graph (evatar_web_graph),
%% bounded: the pairing's descriptions are indexed once by
%% (category, type, provider side), then each unbound entry is explained
%% (bil:explain_unbound/2) against its consumer and at most
%% max_candidates/0 candidate providers, not against every description.
%% One answer costs O(S log S + U (log S + max_candidates)) for S service
%% and consumes entries and U unbound entries.
-module(evatar_web_explain).

-export([index/1, explain/2, consumer/2, max_candidates/0]).

-export_type([index/0]).

-opaque index() :: #{consumers := #{binary() => bil:description()},
                     providers := #{{binary(), binary(), bil:entity_type()} =>
                                        [{binary(), binary(), bil:entry()}]}}.

%% @doc Candidate providers explained per unbound entry; `more' says how
%% many others there were (docs/api.md, "Bindings").
-spec max_candidates() -> pos_integer().
max_candidates() -> 16.

%% @doc Indexes descriptions: each entity's own, and every service entry
%% by (category keyword, type keyword, entity type), in document order.
-spec index([bil:description()]) -> index().
index(Descriptions) ->
    Consumers = lists:foldl(fun(#{entity_id := E} = D, Acc) ->
                                    case maps:is_key(E, Acc) of
                                        true -> Acc;
                                        false -> Acc#{E => D}
                                    end
                            end, #{}, Descriptions),
    Services = [{{key(Ca), key(Ty), T}, {E, C, S}}
                || #{entity_id := E, entity_type := T, components := Cs} <- Descriptions,
                   #{id := C, services := Ss} <- Cs,
                   #{category := Ca, type := Ty} = S <- Ss],
    Providers = maps:map(fun(_, L) -> lists:reverse(L) end,
                         lists:foldl(fun({K, V}, Acc) ->
                                             maps:update_with(K, fun(L) -> [V | L] end, [V], Acc)
                                     end, #{}, Services)),
    #{consumers => Consumers, providers => Providers}.

%% @doc bil:explain_unbound/2's answer for one unbound entry, over at most
%% max_candidates/0 providers, and how many more candidates were left out.
-spec explain(bil:unbound(), index()) ->
          {[#{provider := bil:endpoint(), failed := [{binary(), binary(), [binary()]}]}],
           non_neg_integer()}.
explain(#{consumer := #{entity := E}, category := Cat, type := Type} = Unbound,
        #{consumers := Consumers, providers := Providers}) ->
    case maps:find(E, Consumers) of
        {ok, #{entity_type := ConsumerType} = Consumer} ->
            All = maps:get({key(Cat), key(Type), other(ConsumerType)}, Providers, []),
            {Shown, Rest} = lists:split(min(max_candidates(), length(All)), All),
            Candidates = [#{entity_id => PE, entity_type => other(ConsumerType), api_name => <<>>, context => <<>>,
                            components => [#{id => PC, services => [S], consumes => []}]}
                          || {PE, PC, S} <- Shown],
            {bil:explain_unbound(Unbound, [Consumer | Candidates]), length(Rest)};
        error ->
            {[], 0}
    end.

%% @doc The description of entity `E' (the first one given), if any.
-spec consumer(binary(), index()) -> [bil:description()].
consumer(E, #{consumers := Consumers}) ->
    case maps:find(E, Consumers) of
        {ok, D} -> [D];
        error -> []
    end.

key(Bin) -> bil:keyword(Bin).

other(agent) -> avatar;
other(avatar) -> agent.
